"""The flatten-and-plan pipeline, stage by stage, with timing and the report.

``plan_file`` runs: load -> validate (fill pits) -> simplify (terrain
topology) -> mesh -> flatten -> simulate -> tool paths, by the profile's layout method
(``flatten.method``: ``isoline``, the paper's, or ``free``, a print direction per
triangle), and returns a :class:`Plan` holding
every intermediate result and the ``report`` dict (:mod:`pipeline.report`) whose keys
other tools read (see the README; add keys freely, never rename).
"""

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pipeline import alternatives, fitting, printable, report
from pipeline.input import heightfield as hfio
from pipeline.input.sidecar import settings as sidecar_settings
from pipeline.input.simplify import simplify
from pipeline.input.validate import validate
from pipeline.geometry import on_bed, quarter_turn
from pipeline.layout import curvature
from pipeline.layout.free import FREE_BELOW, flatten_free
from pipeline.layout.reach import reach
from pipeline.layout.isoline import flatten
from pipeline.meshing.grid import build_grid_mesh
from pipeline.meshing.isoline import build_mesh
from pipeline.paths.isoline import plan_toolpaths
from pipeline.problems import (BLOCKING, fold_area_fraction,
                               free_layout_problems, hold_problems, layout_problems,
                               other_method_problems, relief_problems,
                               simulation_problems)
from pipeline.paths.sheet import Sheet
from pipeline.paths.stripes import stripe_toolpaths
from pipeline.simulation.forward import simulate
from pipeline.simulation import fidelity, inverted
from pipeline.simulation.staged import simulate_free
from pipeline.simulation.resample import onto_grid
from pipeline.simulation.shell import directional_rest, simulate_shell, thickness_for


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
    profile : pipeline.profiles.profile.Profile
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
    if profile.flatten.method == "free":
        hf = fitting.fitted(result, hf, profile, sidecar, opts, stage, timing, force_fit)
        result.hf = hf
        _free_sheet(result, hf, profile, stage, timing)
        fitting.refuse_too_high(result, hf, profile, sidecar, opts, timing)
    else:
        _isoline_sheet(result, hf, profile, path, stage, timing, opts)
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
        _alternatives(result, given, profile, opts, section, path.stem, say)
        held = fitting.take_hold(result, sidecar, lambda smooth_mm: plan_file(
            path, profile, progress, force_fit, method, held_smooth_mm=smooth_mm))
        if held is not None:
            return held
    result.report.update(gate=section, printable=result.printable,
                         needs_decision=result.needs_decision, warnings=list(result.problems))
    return result


def _alternatives(result, given, profile, opts, section, name, say):
    """What would print a plan the gate turned down: the other layout method, and for a
    free sheet that ends too far from the shape, the smoothing at which it holds."""
    free = profile.flatten.method == "free"
    say("other_method", "not printable: would the %s method form it?"
        % ("paper's (isoline)" if free else "free"))
    t = time.perf_counter()
    would = alternatives.isoline_would if free else alternatives.free_would
    result.report["other_method"] = would(given, profile)
    result.report["timing_s"]["other_method"] = round(time.perf_counter() - t, 4)
    result.problems += other_method_problems(result.report["other_method"], name)
    if free and "printable.displacement" in section["outside"] and not result.blocked:
        say("hold", "the sheet ends too far from the shape: at which smoothing would it hold?")
        t = time.perf_counter()
        result.report["hold"] = alternatives.smoothing_that_holds(
            result.validated, profile, opts, result.report["heightfield"]["longest_diameter_mm"],
            fit_height_too=result.fit is not None)
        result.report["timing_s"]["hold"] = round(time.perf_counter() - t, 4)
        result.problems += hold_problems(result.report["hold"], opts["smooth_mm"], name)


def _isoline_sheet(result, hf, profile, path, stage, timing, opts):
    """The paper's method: isoline mesh, isoline layout, paths along the isolines."""
    mp = profile.mesh
    t = stage("mesh", "isolines every %.3g mm, gradient lines every %.3g mm"
              % (mp.isoline_step_mm, mp.gradient_spacing_mm))
    mesh = build_mesh(hf, isoline_step_mm=mp.isoline_step_mm,
                      gradient_spacing_mm=mp.gradient_spacing_mm, l_u_mm=mp.l_u_mm,
                      l_sim_mm=mp.l_sim_mm)
    result.mesh = mesh
    timing["mesh"] = time.perf_counter() - t

    fp = profile.flatten
    lim = profile.shrink_limits
    t = stage("flatten", "%d triangles, up to %d iterations" % (len(mesh.faces), fp.iterations))
    weights = fp.weights()
    flat = flatten(mesh, s_min=lim.s_min, s_max=lim.s_max, iterations=fp.iterations,
                   weights=weights)
    result.flat = flat
    timing["flatten"] = time.perf_counter() - t
    # A folded layout is not bad input: the plan goes on so the pictures show where,
    # but where the fold covers more than a sliver of the sheet it is marked not
    # printable (the daemon will not print it); a few flipped triangles at the edge
    # only make paths overlap in a spot.
    result.fold_fraction = fold_area_fraction(flat.xy, mesh.faces)
    result.problems += layout_problems(flat, result.fold_fraction, lim,
                                       Path(path).stem + ".yaml", opts["smooth_mm"])

    t = stage("simulate", "forward simulation of the flat sheet (%s)"
              % ("thin shell" if fp.simulation == "shell" else "the paper's"))
    # The printed sheet can only shrink within the material's range (the G-code clamps
    # the thickness the same way), so the simulation shrinks by the clamped sigma.
    if fp.simulation == "shell":
        sheet = onto_grid(hf, mesh, flat.xy, mp.grid_mm)
        sigma = np.clip(sheet.sigma, lim.s_min, lim.s_max)
        thick = thickness_for(sigma, profile.shrink_curve, profile.layers,
                              profile.thickness_mm.min, profile.thickness_mm.max)
        sim = simulate_shell(sheet.vertices, sheet.faces, sheet.xy,
                             directional_rest(sheet.xy, sheet.faces, sheet.direction, sigma),
                             thick, clamped=int(np.count_nonzero(sigma != sheet.sigma)))
    else:
        sim = simulate(mesh, flat, weights={k: weights[k] for k in
                                            ("bridge", "printing", "bending", "shear")},
                       s_min=lim.s_min, s_max=lim.s_max)
    result.sim = sim
    result.problems += simulation_problems(sim)
    timing["simulate"] = time.perf_counter() - t

    t = stage("toolpath", "paths %.3g mm wide" % profile.path_width_mm)
    result.xy_bed = on_bed(flat.xy, profile.bed_mm)
    tp = profile.toolpath
    result.toolpaths = plan_toolpaths(
        result.xy_bed, mesh.faces, mesh.vertex_level, mesh.printing_edges, flat.sigma,
        profile.path_width_mm, merge_angle_deg=tp.merge_angle_deg, merge_sigma=tp.merge_sigma)
    timing["toolpath"] = time.perf_counter() - t


def _free_sheet(result, hf, profile, stage, timing):
    """The free print direction: a plain mesh, a layout whose direction each triangle
    chooses, the thin-shell simulation of that sheet, and stripe paths along it."""
    mp, fp, lim = profile.mesh, profile.flatten, profile.shrink_limits
    t = stage("mesh", "a plain triangulation every %.3g mm" % mp.grid_mm)
    # The fit solved this very layout (the lowered relief, this mesh, these iterations)
    # on its last step: take it rather than solve it again.
    fit = result.fit
    reuse = fit.layout if fit is not None and fit.applied_scale < 1.0 else None
    mesh = reuse[0] if reuse else build_grid_mesh(hf, mp.grid_mm)
    result.mesh = mesh
    timing["mesh"] = time.perf_counter() - t
    t = stage("flatten", "%d triangles, free direction, up to %d iterations%s"
              % (len(mesh.faces), fp.free_iterations, ", solved by the fit" if reuse else ""))
    flat = reuse[1] if reuse else flatten_free(mesh, lim.s_min, lim.s_max,
                                               iterations=fp.free_iterations)
    # Only curvature along the paths can be programmed: where the layout leaves the
    # direction free, the paths turn the way the target bends most.
    flat = curvature.bend_free_directions(hf, mesh, flat, FREE_BELOW)
    result.flat = flat
    result.reach = reach(hf, mesh, flat, profile)
    timing["flatten"] = time.perf_counter() - t
    result.fold_fraction = fold_area_fraction(flat.xy, mesh.faces)
    result.problems += free_layout_problems(flat, result.fold_fraction)
    t = stage("simulate", "forward simulation of the flat sheet (thin shell)")
    result.curvature, sim = simulate_free(hf, mesh, flat, profile)
    result.sim = sim
    result.problems += simulation_problems(sim)
    timing["simulate"] = time.perf_counter() - t
    t = stage("toolpath", "stripes %.3g mm wide along the print direction"
              % profile.path_width_mm)
    # The layers across are printed on the layout solved again for their shrink: the
    # sheet, its pictures and its files are that layout's.
    flat = result.flat = result.curvature.layout or flat
    result.xy_bed = on_bed(flat.xy, profile.bed_mm)
    tp = profile.toolpath
    # The shrink as printed: the layout's, with what the curvature program added.
    sigma = result.curvature.sigma
    # Crossed layer groups print their own stripes; the lower group's are the plan's
    # paths (pictures, screen print), the upper group's are printed above them.
    sheet = Sheet(result.xy_bed, mesh.faces)

    def stripes(direction, shrink=sigma):
        return stripe_toolpaths(result.xy_bed, mesh.faces, direction, shrink,
                                profile.path_width_mm, merge_angle_deg=tp.merge_angle_deg,
                                merge_sigma=tp.merge_sigma, level=mesh.vertex_level,
                                join_factor=tp.hop_reach_widths,
                                over_factor=tp.hop_over_widths, sheet=sheet,
                                rim_tail_factor=tp.rim_tail_widths)
    lower, upper = result.curvature.group_directions(flat.direction)
    result.toolpaths = stripes(lower)
    result.upper_toolpaths = stripes(upper) if result.curvature.crossed else None
    lam = result.curvature.laminate
    if lam is not None:
        # The layers across print stripes a quarter turn from the plan's.
        result.across_toolpaths = stripes(quarter_turn(flat.direction),
                                          lam.layer_sigma[:, lam.across].max(axis=1))
    timing["toolpath"] = time.perf_counter() - t
