"""What is wrong with a plan, as report problems: each a dict of a stable ``code``, a
``message`` saying what and where, and a ``fix`` saying what to change.

The layout methods, the simulation and the method check each have theirs; the plan
collects them, and :data:`BLOCKING` names the ones after which printing is pointless.
"""

import numpy as np

from pipeline.geometry import signed_areas_2d
from pipeline.layout.isoline import SIGMA_TOL

# Above this invalid-edge fraction the report warns (the paper's models: 0.4-4.7 %).
INVALID_WARN = 0.10
# Folded (flipped) area, as a fraction of the flat sheet, above which a plan is not printable.
FOLD_LIMIT = 0.001
# Above this share of the sheet the free layout's plan warns (the target: 2 %).
INVALID_AREA_WARN = 0.02
# Problems after which a print is pointless.
BLOCKING = ("flatten.overlap", "fit.too_high")


def fold_area_fraction(xy, faces):
    """Area of the flipped triangles over the whole flat area (0 for an embedding)."""
    area = signed_areas_2d(xy, faces)
    total = np.abs(area).sum()
    return float(-area[area < 0].sum() / total) if total > 0 else 0.0


def layout_problems(flat, fold_fraction, lim, sidecar_name="NAME.yaml", smooth_mm=1.0):
    """What is wrong with a flat layout, as report problems (code, message, fix).

    The fixes are the ones that helped on the real terrain of the tests
    (``../shared/data/terrain``): there smoothing (``smooth_mm`` 3 mm instead of 1)
    turned folded layouts into printable ones, while a lower height or more flatten
    iterations made them fold more; so smoothing is offered for folds, from where the
    file stands (twice its present ``smooth_mm``), and the free method, which folds less.
    """
    problems = []
    if flat.overlapping:
        problems.append({
            "code": "flatten.overlap" if fold_fraction > FOLD_LIMIT else "flatten.small_fold",
            "message": "the flattened layout folds over itself (%d flipped triangles, %d "
                       "boundary crossings, %.3f %% of the sheet): paths there would overlap"
                       % (flat.flipped_triangles, flat.boundary_intersections,
                          100 * fold_fraction),
            "fix": "smooth away features narrower than the sheet can form: raise smooth_mm in "
                   "the sidecar (%s) from %g, e.g. `smooth_mm: %g`, or plan it with the free "
                   "layout method (`method: free` there), which forms saddles and valleys; a "
                   "lower height or more flatten iterations do not help"
                   % (sidecar_name, smooth_mm, max(3.0, 2.0 * smooth_mm))})
    if flat.invalid_edge_fraction > INVALID_WARN:
        sigma = np.asarray(flat.sigma)
        stretch = float(np.mean(sigma < lim.s_min - SIGMA_TOL))
        over = float(np.mean(sigma > lim.s_max + SIGMA_TOL))
        problems.append({
            "code": "flatten.invalid_edges",
            "message": "%.1f %% of the printing edges need a shrink outside %.3g..%.3g; the "
                       "sheet will not reach the shape there (%.1f %% would have to stretch, "
                       "%.1f %% shrink more than the material can)" % (
                           100 * flat.invalid_edge_fraction, lim.s_min, lim.s_max,
                           100 * stretch, 100 * over),
            "fix": "see NAME.stress.png for where: edges that would have to stretch lie in "
                   "saddles and valleys, which a sheet that only shrinks cannot form exactly "
                   "(smoothing, smooth_mm, removes the narrow ones); edges that would shrink "
                   "too much need a lower height there"})
    return problems


def free_layout_problems(flat, fold_fraction):
    """What is wrong with a free-direction layout, as report problems (code, message, fix)."""
    problems = []
    if flat.flipped:
        problems.append({
            "code": "flatten.overlap" if fold_fraction > FOLD_LIMIT else "flatten.small_fold",
            "message": "the flattened layout folds over itself (%d flipped triangles, %.3f %% "
                       "of the sheet)" % (flat.flipped, 100 * fold_fraction),
            "fix": "raise smooth_mm in the sidecar, or lower the relief (height_mm)"})
    if flat.invalid_area_fraction > INVALID_AREA_WARN:
        problems.append({
            "code": "flatten.invalid_area",
            "message": "%.1f %% of the sheet needs a map the material cannot make (%.1f %% "
                       "would have to stretch, %.1f %% shrink more than it can or in two "
                       "directions at once)" % (100 * flat.invalid_area_fraction,
                                                100 * flat.stretch_area_fraction,
                                                100 * flat.overshrink_area_fraction),
            "fix": "the slopes are steeper than a sheet that shrinks at most by s_max can "
                   "form: lower the relief (height_mm in the sidecar) or smooth it "
                   "(smooth_mm); NAME.stress.png shows where"})
    return problems


def simulation_problems(sim):
    """A warning when the forward simulation stopped before the sheet came to rest.

    Its figures are then where the sheet stood: on the reference shapes the ones
    still moving (parts that bend without stretching) move further from the
    target as they settle, the starfish from 2.3 % of its diameter at 600
    iterations to 2.9 % at rest.
    """
    if sim.converged:
        return []
    return [{"code": "simulate.not_at_rest",
             "message": "the simulated sheet was still moving after %d iterations: its "
                        "displacement (mean %.2f mm) is where it stood then, and parts that "
                        "bend without stretching (arms, lobes, a long gentle skirt) tend to "
                        "move further from the target as they settle"
                        % (sim.iterations, sim.mean_displacement_mm),
             "fix": "nothing to change for printing; read the displacement as a first "
                    "estimate, and NAME.preview.png for where the sheet departs"}]


# A sheet that misses the shape by more than this share of its relief (on average)
# does not show its hills and valleys, however small a share of its diameter that is:
# the reference shapes miss by 1-5 % of their relief, the real tiles by half of it.
RELIEF_LOST = 0.25


def relief_problems(mean_displacement_mm, relief_mm, name):
    """A warning when the simulated sheet misses the shape by a good part of its relief:
    the features are narrower than the sheet can bend into."""
    if not relief_mm > 0 or mean_displacement_mm <= RELIEF_LOST * relief_mm:
        return []
    return [{"code": "simulate.relief",
             "message": "the simulated sheet ends %.1f mm from the shape on average, %.0f %% of "
                        "its %.1f mm relief: its hills and valleys will hardly show (features "
                        "narrower than this sheet can bend into do not form)"
                        % (mean_displacement_mm, 100 * mean_displacement_mm / relief_mm,
                           relief_mm),
             "fix": "smooth the input by a few mm (`smooth_mm` in %s.yaml) to print the shape "
                    "that forms, and compare %s.preview.png" % (name, name)}]


def other_method_problems(other, name):
    """A note on a plan that is not printable: whether the other layout method forms it."""
    method = other["method"]
    label = "the free layout method" if method == "free" else "the paper's (isoline) layout method"
    if not other["would_form"]:
        why = (("its mesher stops: %s" % other["error_message"]) if "error" in other else
               "%.0f %% of the sheet outside what the material can make, %d folded triangles"
               % (100 * other["invalid_area_fraction"], other["flipped"]))
        return [{"code": "plan.other_method",
                 "message": "%s does not form it either (%s)" % (label, why),
                 "fix": "lower or smooth the relief (height_mm, smooth_mm in %s.yaml)" % name}]
    return [{"code": "plan.other_method",
             "message": "%s forms this sheet (%.1f %% of it outside what the material can "
                        "make, no folds)" % (label, 100 * other["invalid_area_fraction"]),
             "fix": "write `method: %s` in %s.yaml (or plan with `hostd plan --method %s`)"
                    % (method, name, method)}]


def hold_problems(hold, smooth_mm, name):
    """A note on a free plan whose sheet ends too far from the shape: the smoothing at
    which it would hold (the report's ``hold``), as the sidecar line to write."""
    if not hold["tried"]:
        return []
    worst = max(hold["tried"], key=lambda t: t[0])
    if hold["smooth_mm"] is None:
        return [{"code": "plan.hold",
                 "message": "smoothed as much as %g mm the simulated sheet still ends %.1f %% "
                            "of its diameter and %.0f %% of its relief from the shape (it "
                            "holds within %.1f %% and %.0f %%)"
                            % (worst[0], 100 * worst[1], 100 * worst[4], 100 * hold["limit"],
                               100 * RELIEF_LOST),
                 "fix": "lower the relief (height_mm in %s.yaml)" % name}]
    got = next(t for t in hold["tried"] if t[0] == hold["smooth_mm"])
    return [{"code": "plan.hold",
             "message": "smoothed to %g mm instead of %g mm the sheet holds the shape: it "
                        "ends %.1f %% of its diameter and %.0f %% of its relief from it "
                        "(simulated on a %g mm mesh, %.1f mm high); features narrower than "
                        "that do not form in this sheet"
                        % (hold["smooth_mm"], smooth_mm, 100 * got[1], 100 * got[4],
                           hold["grid_mm"], got[3]),
             "fix": "write `smooth_mm: %g` in %s.yaml to print the smoothed shape"
                    % (hold["smooth_mm"], name)}]
