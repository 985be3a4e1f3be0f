"""The daemon's one exception family; the edges (CLI, logs, web) turn it into messages.

``code`` is stable (tests and tools match on it), e.g. ``config.unknown_key``.
"""


class HostdError(Exception):
    """A daemon-side error a person can act on.

    Parameters
    ----------
    message : str
        What is wrong.
    code : str
        Stable machine-readable code.
    file : str, optional
        The file concerned (config, input, state database).
    key : str, optional
        The key inside that file (dotted path), for config errors.
    fix : str, optional
        How to fix it.
    """

    def __init__(self, message, *, code="hostd.error", file=None, key=None, fix=None):
        self.code = code
        self.message = message
        self.file = None if file is None else str(file)
        self.key = key
        self.fix = fix
        super().__init__(self.text())

    def text(self):
        parts = [self.file + ": " if self.file else "", self.message]
        if self.key:
            parts.append(" (key %s)" % self.key)
        if self.fix:
            parts.append(". Fix: " + self.fix)
        return "".join(parts)
