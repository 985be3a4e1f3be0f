"""What would make a plan that is not printable print: the other layout method, and for a
free sheet that does not hold its shape, the least smoothing at which it would.

Each is a quick look, asked only of a plan the gate turned down (``look``), and answered
as a report section; :mod:`pipeline.problems` words it as a note with the sidecar line.
"""

import time

import numpy as np

from pipeline.errors import PipelineError
from pipeline.input.simplify import simplify
from pipeline.layout import curvature
from pipeline.layout.fit import fit_height, least_smoothing, program_relief, scaled
from pipeline.layout.free import FREE_BELOW, flatten_free
from pipeline.layout.isoline import flatten
from pipeline.meshing.grid import build_grid_mesh
from pipeline.meshing.isoline import build_mesh
from pipeline.problems import (FOLD_LIMIT, RELIEF_LOST, fold_area_fraction, hold_problems,
                               other_method_problems)
from pipeline.simulation.staged import simulate_free

# The free method's quick looks: a coarser grid and fewer iterations than its plan (a
# few seconds on a 175 mm tile); the thin shell's displacement changes by less than a
# tenth from this grid to the plan's.
QUICK_GRID_MM = 2.0
QUICK_ITERATIONS = 30
# The smoothing looked for doubles up to this share of the field's longest side: on the
# real tiles the sheet holds within 3 % at 6 mm, a sixteenth of their side.
HOLD_CAP = 0.1


def look(result, given, method, other, opts, section, say):
    """What would print a plan the gate turned down: the report's ``other_method``, the
    other layout method's look at the relief as given, and for a method with a hold look
    (``method.hold_look``) whose sheet ends too far from the shape, its ``hold``, the
    smoothing at which it holds; each with its timing and its note in the problems.

    result : the Plan; given : the HeightField before any fit; method, other : the plan's
    layout method and the other one (:func:`pipeline.layout.method.method_for`); opts :
    the sidecar's settings; section : the gate's; say : callable(stage, message)."""
    say("other_method", "not printable: would the %s method form it?" % other.title)
    t = time.perf_counter()
    result.report["other_method"] = other.would(given, result.profile)
    result.report["timing_s"]["other_method"] = round(time.perf_counter() - t, 4)
    result.problems += other_method_problems(result.report["other_method"], result.name)
    if method.hold_look and "printable.displacement" in section["outside"] and not result.blocked:
        say("hold", "the sheet ends too far from the shape: at which smoothing would it hold?")
        t = time.perf_counter()
        result.report["hold"] = smoothing_that_holds(
            result.validated, result.profile, opts,
            result.report["heightfield"]["longest_diameter_mm"],
            fit_height_too=result.fit is not None)
        result.report["timing_s"]["hold"] = round(time.perf_counter() - t, 4)
        result.problems += hold_problems(result.report["hold"], opts["smooth_mm"], result.name)


def free_would(hf, profile):
    """Whether the free layout method would form this sheet: its invalid area and folds."""
    lim = profile.shrink_limits
    mesh = build_grid_mesh(hf, max(profile.mesh.grid_mm, QUICK_GRID_MM))
    flat = flatten_free(mesh, lim.s_min, lim.s_max, iterations=QUICK_ITERATIONS)
    would = (flat.flipped == 0
             and flat.invalid_area_fraction <= profile.printable.max_invalid_area)
    return {"method": "free", "invalid_area_fraction": float(flat.invalid_area_fraction),
            "flipped": int(flat.flipped), "would_form": bool(would)}


def isoline_would(hf, profile):
    """Whether the paper's layout method would form this relief (as given, not fitted):
    its invalid area and folds, or the error its mesher stops with. Its layout is
    solved at the plan's own mesh size: on the real tiles a coarser one answers
    differently (the coast tile 54 % invalid at the plan's size, 37 % at twice it)."""
    mp, lim, fp = profile.mesh, profile.shrink_limits, profile.flatten
    out = {"method": "isoline"}
    try:
        mesh = build_mesh(hf, isoline_step_mm=mp.isoline_step_mm,
                          gradient_spacing_mm=mp.gradient_spacing_mm, l_u_mm=mp.l_u_mm)
        flat = flatten(mesh, s_min=lim.s_min, s_max=lim.s_max, iterations=fp.iterations,
                       weights=fp.weights())
    except PipelineError as err:
        # What and where only: the error's own fix is for a plan of that method, and
        # the note that quotes it says what to do about this one.
        where = " (at %s)" % err.where if err.where else ""
        return {**out, "would_form": False, "error": err.code,
                "error_message": err.message + where}
    fold = fold_area_fraction(flat.xy, mesh.faces)
    would = fold <= FOLD_LIMIT and flat.invalid_area_fraction <= profile.printable.max_invalid_area
    return {**out, "invalid_area_fraction": float(flat.invalid_area_fraction),
            "flipped": int(flat.flipped_triangles), "fold_area_fraction": fold,
            "would_form": bool(would)}


def smoothing_that_holds(validated, profile, opts, diameter_mm, fit_height_too):
    """The least smoothing at which the simulated free sheet ends within the profile's
    displacement limit and shows its relief (misses it by at most ``RELIEF_LOST`` of it):
    the report's ``hold`` section (``smooth_mm``, None where none up to the cap holds;
    ``tried``: [smooth_mm, displacement share, relief scale, relief mm, displacement
    over relief] per look; ``failed``: [smooth_mm, error code] where a look could not
    plan it).

    A thin sheet cannot bend into features much narrower than it is stiff (the real
    tiles' ridges, a few mm across, come out as one smooth hill); smoothed, the same
    terrain forms, and, no longer bound by its steepest narrow slopes, at a higher
    relief. validated : the HeightField as validated, before any smoothing; opts : the
    sidecar's settings (``min_prominence_mm``, ``smooth_mm``); diameter_mm : the
    longest diameter the displacement is a share of; fit_height_too : the plan fitted
    the relief, so each look fits it anew (else the relief is as given).
    """
    t0 = time.perf_counter()
    lim, limit = profile.shrink_limits, profile.printable.max_mean_displacement
    size = max(validated.z.shape) * validated.pixel_mm
    # A small field on the quick grid would be a few cells across: there the plan's own.
    grid = float(np.clip(size / 50.0, profile.mesh.grid_mm, QUICK_GRID_MM))
    tried, failed = [], []

    def holds(smooth):
        # A look is advice: an input it cannot plan (smoothed away, say) does not hold,
        # and the plan itself stands.
        try:
            return look(smooth)
        except PipelineError as err:
            failed.append([float(smooth), err.code])
            return False

    def look(smooth):
        hf = simplify(validated, opts["min_prominence_mm"], smooth)[0]
        scale = 1.0
        if fit_height_too:
            scale = fit_height(hf, lim.s_min, lim.s_max, smooth, grid_mm=grid,
                               fine_steps=0).applied_scale
            hf = scaled(hf, scale)
        mesh = build_grid_mesh(hf, grid)
        flat = flatten_free(mesh, lim.s_min, lim.s_max, iterations=QUICK_ITERATIONS)
        # The curvature as the plan smoothed this much would program it.
        program = program_relief(validated, opts["min_prominence_mm"], smooth, profile, scale)
        flat = curvature.bend_free_directions(hf if program is None else program, mesh, flat,
                                              FREE_BELOW)
        # The sheet as the plan would print it, its layer groups turned apart and two
        # layers across where those rest closer: with paths along d only the advice
        # asked for more smoothing than the plan then needs (the real tiles 4 and 6 mm
        # where 3 and 4 hold), at half the look's time.
        _, sim = simulate_free(hf, mesh, flat, profile, relief=program)
        share = sim.mean_displacement_mm / diameter_mm
        relief = float(np.nanmax(hf.z) - np.nanmin(hf.z))
        lost = sim.mean_displacement_mm / max(relief, 1e-9)
        tried.append([float(smooth), round(float(share), 5), round(float(scale), 4),
                      round(relief, 2), round(float(lost), 4)])
        return flat.flipped == 0 and share <= limit and lost <= RELIEF_LOST

    cap = HOLD_CAP * size
    found = least_smoothing(holds, opts["smooth_mm"], cap_mm=cap)
    return {"smooth_mm": found, "limit": limit, "grid_mm": grid, "cap_mm": round(cap, 2),
            "tried": tried, "failed": failed, "seconds": round(time.perf_counter() - t0, 2)}
