"""The flatten-and-plan pipeline, stage by stage, with timing and the report.

``plan_file`` runs: load -> validate (fill pits) -> simplify (terrain
topology) -> mesh -> flatten -> simulate -> tool paths, by the profile's layout method
(``flatten.method``: ``isoline``, the paper's, or ``free``, a print direction per
triangle; :func:`pipeline.layout.method.method_for` finds the stages of each by name),
and returns a :class:`Plan` holding every intermediate result and the ``report`` dict
(:mod:`pipeline.report`) whose keys other tools read (see the README; add keys freely,
never rename).
"""

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from pipeline import alternatives, fitting, printable, report
from pipeline.input import heightfield as hfio
from pipeline.input.sidecar import settings as sidecar_settings
from pipeline.input.simplify import simplify
from pipeline.input.validate import validate
from pipeline.layout.method import method_for
from pipeline.problems import BLOCKING, relief_problems
from pipeline.simulation import fidelity, inverted


@dataclass
class Plan:
    """Everything one run of the pipeline produced (arrays in mm)."""

    name: str
    profile: object
    input_hf: object = None
    hf: object = None
    sidecar: object = None
    mesh: object = None
    flat: object = None
    sim: object = None
    xy_bed: object = None
    toolpaths: object = None
    upper_toolpaths: object = None
    across_toolpaths: object = None
    simplified: dict = field(default_factory=dict)
    curvature: object = None
    reach: dict = None
    fit: object = None
    # The relief the curvature program reads, where the plan smoothed the target
    # (:func:`pipeline.fitting.program_relief`); None: the target itself.
    relief: object = None
    inverted: dict = None
    validated: object = None
    problems: list = field(default_factory=list)
    fold_fraction: float = 0.0
    report: dict = field(default_factory=dict)

    @property
    def printable(self):
        """False when a problem makes printing pointless (the layout folds, or the relief
        asked for cannot form) or the plan is outside the profile's printable limits."""
        return not self.blocked and not self.needs_decision

    @property
    def blocked(self):
        """A problem makes printing pointless."""
        return any(p["code"] in BLOCKING for p in self.problems)

    @property
    def needs_decision(self):
        """Outside the profile's printable limits: a person decides whether to print."""
        return not self.blocked and any(p["code"] in printable.CODES for p in self.problems)


STAGES = ("load", "validate", "mesh", "flatten", "simulate", "toolpath")


def plan_file(path, profile, progress=None, force_fit=False, method=None, held_smooth_mm=None):
    """Run the pipeline on one input file.

    Parameters
    ----------
    path : str or Path, the height field (image, array or mesh)
    profile : pipeline.profiles.schema.Profile
    progress : callable(stage, message), optional
    force_fit : fit the relief (free method) even where the sidecar asks for a height
    method : the layout method, over the sidecar's ``method`` and the profile's
    held_smooth_mm : the smoothing at which a first plan's sheet held its shape
        (:func:`pipeline.fitting.take_hold`): planned with it, and no further looks

    Returns
    -------
    Plan

    Raises
    ------
    pipeline.errors.PipelineError (with a stable ``code``) on invalid input.
    """
    path = Path(path)
    say = progress or (lambda stage, msg: None)
    timing = {}
    t_all = time.perf_counter()
    result = Plan(name=path.stem, profile=profile)

    def stage(name, msg):
        say(name, msg)
        return time.perf_counter()

    t = stage("load", "reading %s" % path.name)
    hf, sidecar = hfio.load(path, profile=profile)
    result.input_hf, result.sidecar = hf, sidecar
    hf, _ = hfio.coarsen(hf, profile.validate.working_pixel_mm)
    timing["load"] = time.perf_counter() - t

    method = method or sidecar.method
    if method and method != profile.flatten.method:
        profile = replace(profile, flatten=replace(profile.flatten, method=method))
        result.profile = profile
    opts = sidecar_settings(sidecar, profile)
    if held_smooth_mm is not None:
        opts["smooth_mm"] = held_smooth_mm
    t = stage("validate", "checking topology, filling pits up to %.3g mm" % opts["max_fill_mm"])
    hf, vrep = validate(hf, opts["max_fill_mm"], bed_mm=profile.bed_mm)
    result.validated = hf
    hf, srep = simplify(hf, opts["min_prominence_mm"], opts["smooth_mm"])
    result.simplified = srep
    timing["validate"] = time.perf_counter() - t
    result.hf = hf

    given = hf
    layout = method_for(profile.flatten.method)
    hf = result.hf = layout.prepare(result, hf, profile, sidecar, opts, stage, timing, force_fit)
    result.relief = fitting.program_relief(result, opts, profile, held_smooth_mm)
    layout.sheet(result, hf, profile, path, stage, timing, opts)
    layout.after(result, hf, profile, sidecar, opts, timing)
    result.inverted = inverted.settled_inverted(result.sim, result.mesh)
    result.problems += inverted.problems(result.inverted, path.stem)
    timing["total"] = time.perf_counter() - t_all
    result.report = report.of_plan(path, profile, result, vrep, srep, timing)
    t = time.perf_counter()
    result.report["fidelity"] = fidelity.of_plan(result, profile)
    result.report["timing_s"]["fidelity"] = round(time.perf_counter() - t, 4)
    result.problems += relief_problems(result.sim.mean_displacement_mm,
                                       result.report["simulation"]["relief_mm"], path.stem)
    section, problems = printable.gate(result.report, profile.printable, path.stem)
    result.problems += problems
    if not result.printable and held_smooth_mm is None:
        alternatives.look(result, given, layout, method_for(layout.other), opts, section, say)
        held = fitting.take_hold(result, sidecar, lambda smooth_mm: plan_file(
            path, profile, progress, force_fit, method, held_smooth_mm=smooth_mm))
        if held is not None:
            return held
    result.report.update(gate=section, printable=result.printable,
                         needs_decision=result.needs_decision, warnings=list(result.problems))
    return result
