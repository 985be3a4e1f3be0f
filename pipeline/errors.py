"""The pipeline's one exception family.

Every error carries a stable ``code`` (tools and tests match on it, so never
rename one), the file it concerns, where in it (in mm where it is geometric),
and how to fix it. The edges (CLI, daemon, web) turn these into messages.
"""


class PipelineError(Exception):
    """Base of all pipeline errors.

    Parameters
    ----------
    code : str
        Stable machine-readable code, e.g. ``"heightfield.truncated"``.
    message : str
        What is wrong, in words a person can act on.
    file : str, optional
        The file concerned (input, sidecar or profile).
    where : str, optional
        Where in the file: a key, a pixel, or a position in mm.
    fix : str, optional
        How to fix it.
    """

    default_code = "pipeline.error"

    def __init__(self, message, *, code=None, file=None, where=None, fix=None, details=None):
        self.code = code or self.default_code
        self.message = message
        self.file = None if file is None else str(file)
        self.where = where
        self.fix = fix
        self.details = dict(details or {})
        super().__init__(self.text())

    def text(self):
        """One human-readable paragraph: what, where, how to fix."""
        parts = []
        if self.file:
            parts.append(self.file + ": ")
        parts.append(self.message)
        if self.where:
            parts.append(" (at " + str(self.where) + ")")
        text = "".join(parts)
        if self.fix:
            text += ". Fix: " + self.fix
        return text

    def to_dict(self):
        return {"code": self.code, "message": self.message, "file": self.file,
                "where": self.where, "fix": self.fix, "details": self.details,
                "text": self.text()}


class InvalidHeightField(PipelineError):
    """The input file cannot become a printable height field."""
    default_code = "heightfield.invalid"


class InvalidSidecar(PipelineError):
    """The ``NAME.yaml`` beside an input is malformed or has unknown keys."""
    default_code = "sidecar.invalid"


class InvalidProfile(PipelineError):
    """A printer profile is malformed, incomplete or physically inconsistent."""
    default_code = "profile.invalid"


class MeshingError(PipelineError):
    """The height field could not be meshed into isolines and gradient lines."""
    default_code = "mesh.failed"


class PlanError(PipelineError):
    """A later stage (flatten, tool paths, G-code) cannot produce a valid plan."""
    default_code = "plan.failed"
