"""How high a height field can be and still form: the largest relief the material allows.

A sheet that loses at most ``s_max`` of its length in one direction cannot form slopes
much steeper than ``acos(1 - s_max)`` (about 49 degrees for 34 %), nor regions that
must shrink in two directions at once. Real elevation data is drawn with 20-40x
vertical exaggeration, and its cliffs and scarps exceed that: a slightly lower relief
prints, the asked-for one does not.

:func:`fit_height` finds the largest height scale at which the free-direction layout
leaves at most ``target`` of the sheet outside the admissible set, with no flips: a
bound from the slopes, then a bisection of quick layout solves on a coarse mesh.

Real terrain fails a second limit as well: its narrow ridges and valleys bend further
than any stack of the sheet's thickness can curl (:mod:`pipeline.layout.reach`), and
lowering the relief lowers that curvature only in proportion (the coast tile, lowered to
0.29 of its relief until its layout formed, still needed more than the stack can give
over a sixth of the sheet and settled 5.3 % of its diameter off). Smoothing removes
just those features: smoothed 6 mm the same tile forms its full relief within 0.95 %.
So the fit, where it may (``smooth_first``), looks for the least smoothing at which the
relief as given both lays out and lies within reach before it lowers the relief.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import HeightField
from pipeline.input.simplify import simplify
from pipeline.layout.free import flatten_free
from pipeline.meshing.grid import build_grid_mesh

TARGET = 0.02


@dataclass
class Fit:
    """The fit of one height field.

    requested_height_mm : the relief as given; max_height_mm : the largest that forms;
    applied_scale : the scale the plan uses (1 when the relief was kept); reason : why;
    tried : [(scale, invalid area fraction, flipped triangles)] of every solve.
    min_smooth_mm : the second lever: the least smoothing at which the relief as given
    forms (None: none up to the cap, or not looked for); smooth_tried : its solves,
    [(smooth_mm, invalid area fraction, flipped triangles)]; smooth_seconds : their time
    (part of ``seconds``). layout : (mesh, FreeLayout) of the solve on the plan's own
    mesh at ``applied_scale``, when there was one: the plan's layout, not solved again.
    sidecar_per_mm : the sidecar's ``height_mm`` per mm of the relief planned (the input
    is smoothed after its height is set, which lowers its peaks).
    applied_smooth_mm : the smoothing the plan applies (``min_smooth_mm``) instead of
    lowering the relief, None where it applies none; reach_given : the relief as
    given against the stack's curvature limit (:func:`pipeline.layout.reach.reach`, on
    the quick mesh); smooth_reach : [(smooth_mm, reach p90)] of the smoothing solves;
    removed_mm : the mean height change (mm) the plan makes to the input by the lever it
    applies (smoothing or lowering), None where it applies none; smoothed : the input
    smoothed ``applied_smooth_mm``, the field the plan then takes. keep : what would form
    the input as given (:mod:`pipeline.layout.keep`), None where not looked at.
    removed_p90_mm : the 90th percentile of the height change; removed_map : (rows, cols)
    mm, the change per sample (NaN outside); local : the smoothing was applied only where
    the sheet cannot form the input (:mod:`pipeline.layout.local`): ``{"blend_mm",
    "moved_share"}`` (the share of the footprint moved more than 0.1 mm), else None.
    """

    requested_height_mm: float
    max_height_mm: float
    applied_scale: float
    smooth_mm: float
    reason: str
    tried: list = field(default_factory=list)
    seconds: float = 0.0
    min_smooth_mm: float = None
    smooth_tried: list = field(default_factory=list)
    smooth_seconds: float = 0.0
    layout: tuple = None
    sidecar_per_mm: float = 1.0
    applied_smooth_mm: float = None
    reach_given: dict = None
    smooth_reach: list = field(default_factory=list)
    removed_mm: float = None
    smoothed: HeightField = None
    keep: dict = None
    removed_p90_mm: float = None
    removed_map: np.ndarray = None
    local: dict = None

    def report(self):
        """The report's ``fit`` section."""
        return {"max_height_mm": round(self.max_height_mm, 2),
                "requested_height_mm": round(self.requested_height_mm, 2),
                "applied_scale": round(self.applied_scale, 4), "smooth_mm": self.smooth_mm,
                "reason": self.reason, "solves": len(self.tried),
                "tried": [[round(s, 4), round(a, 4), int(f)] for s, a, f in self.tried],
                "min_smooth_mm": self.min_smooth_mm,
                "smooth_tried": [[s, round(a, 4), int(f)] for s, a, f in self.smooth_tried],
                "seconds": round(self.seconds, 2), "smooth_seconds": round(self.smooth_seconds, 2),
                "layout_reused": self.layout is not None,
                "sidecar_height_mm": self.sidecar_height_mm(),
                "applied_smooth_mm": self.applied_smooth_mm, "reach_given": self.reach_given,
                "smooth_reach": [[sm, round(p, 4)] for sm, p in self.smooth_reach],
                "removed_mm": None if self.removed_mm is None else round(self.removed_mm, 3),
                "removed_p90_mm": (None if self.removed_p90_mm is None
                                   else round(self.removed_p90_mm, 3)),
                "smoothing": "local" if self.local is not None else "global",
                **({"local": self.local} if self.local is not None else {}),
                **({"keep": self.keep} if self.keep is not None else {})}

    def requested_sidecar_mm(self):
        """The relief as given, in the sidecar's terms (mm)."""
        return self.requested_height_mm * self.sidecar_per_mm

    def sidecar_height_mm(self):
        """The sidecar's ``height_mm`` that gives the largest relief that forms."""
        return float(np.floor(self.max_height_mm * self.sidecar_per_mm * 10) / 10)

    def sidecar_line(self):
        """The sidecar line that asks for the largest relief that forms."""
        return "height_mm: %.1f" % self.sidecar_height_mm()

    def smoothing_advice(self):
        """The other way to make it form, keeping the height: ' or ...' or ''."""
        if self.min_smooth_mm is None or self.applied_smooth_mm is not None:
            return ""
        return " or keep the height and smooth it (`smooth_mm: %g` in the sidecar)" % (
            self.min_smooth_mm)


def least_smoothing(forms, smooth_mm, cap_mm=None, step_mm=0.5):
    """The second lever: the least smoothing at which the relief as given forms.

    forms : callable(smooth_mm) -> bool, a quick layout solve of the input smoothed that
    much. Doubles from twice ``smooth_mm`` (at least 2 mm) up to ``cap_mm``, then tries
    once halfway back to the last that did not form (to ``step_mm``): the answer is
    within a quarter of itself in a few solves. Returns smooth_mm or None.
    """
    below, s = smooth_mm, max(2.0 * smooth_mm, 2.0)
    while cap_mm is None or s <= cap_mm:
        if forms(s):
            mid = np.round((below + s) / 2 / step_mm) * step_mm
            return float(mid) if below < mid < s and forms(float(mid)) else float(s)
        below, s = s, s * 2.0
    return None


def program_share(profile):
    """How much of the plan's own smoothing the curvature program reads the relief at
    (``curvature.program_smoothing``); 1 with the local fit, which keeps the detail that
    forms in the target itself (with both, the Vancouver tile held at 2 mm instead of 3
    and ended 3.0 % of its diameter from its target, past the printable limit)."""
    if profile.flatten.fit_smoothing == "local":
        return 1.0
    return profile.curvature.program_smoothing


def program_relief(validated, min_prominence_mm, smooth_mm, profile, scale=1.0):
    """The relief the curvature program of a target smoothed ``smooth_mm`` (from
    ``validated``, as the plan smooths it) reads: ``validated`` smoothed
    :func:`program_share` as much, lowered to ``scale``; None where that share is 1 (the
    target itself). See :func:`pipeline.fitting.program_relief`."""
    share = program_share(profile)
    if share >= 1.0:
        return None
    relief = simplify(validated, min_prominence_mm, smooth_mm * share)[0]
    return relief if scale >= 1.0 else scaled(relief, scale)


def scaled(hf, scale):
    """``hf`` with its relief (height above its lowest point) times ``scale``."""
    z = np.asarray(hf.z, dtype=float)
    base = np.nanmin(z)
    return HeightField(base + (z - base) * scale, hf.pixel_mm, color=hf.color, source=hf.source)


def slope_bound(hf, s_max, share=0.98):
    """A scale under which the steepest slopes (the ``share`` percentile) stay below what
    the material can form, ``acos(1 - s_max)``: a cheap start for the search."""
    gy, gx = np.gradient(np.asarray(hf.z, dtype=float), hf.pixel_mm)
    slope = np.hypot(gx, gy)
    slope = slope[np.isfinite(slope)]
    if not len(slope):
        return 1.0
    steep = float(np.percentile(slope, 100 * share))
    limit = np.tan(np.arccos(1.0 - s_max))
    return 1.0 if steep <= limit else limit / steep


def fit_height(hf, s_min, s_max, smooth_mm=0.0, target=TARGET, grid_mm=None,
               iterations=30, steps=3, fine_mm=1.0, fine_steps=6, fine_iterations=50,
               resmooth=None, reach_of=None, smooth_first=False):
    """The largest relief scale (<= 1) at which ``hf`` forms with the free layout.

    hf : validated HeightField; grid_mm : the search's mesh spacing (default: an 80th of
    the field's longest side, at least 2 mm: coarser than the plan's, and on the safe
    side of it); steps : bisection solves after the bounds on that mesh; fine_mm,
    fine_steps, fine_iterations : then a few on the plan's own mesh spacing and
    iterations, up from the coarse answer, so the fit is the largest relief the plan
    forms, not a coarse mesh's. resmooth : callable(smooth_mm) -> HeightField; where
    given and the relief does not form, :func:`least_smoothing` looks for the second
    lever (capped at a tenth of the field's longest side). reach_of : callable(hf,
    mesh, flat) -> :func:`pipeline.layout.reach.reach`; where given, a relief forms only
    within the stack's curvature reach too. smooth_first : apply the second lever where
    it forms the relief as given (``applied_smooth_mm``; the relief is then not lowered).
    Returns :class:`Fit` (``applied_scale`` is the fitted scale; the caller decides
    whether to apply it).
    """
    t0 = time.perf_counter()
    z = np.asarray(hf.z, dtype=float)
    relief = float(np.nanmax(z) - np.nanmin(z))
    rows, cols = z.shape
    grid = grid_mm or max(2.0, max(rows, cols) * hf.pixel_mm / 80.0)
    tried, formed, given = [], {}, {}

    def ok(scale, spacing=grid, its=iterations):
        mesh = build_grid_mesh(scaled(hf, scale), spacing)
        flat = flatten_free(mesh, s_min, s_max, iterations=its)
        tried.append((float(scale), float(flat.invalid_area_fraction), int(flat.flipped)))
        good = flat.invalid_area_fraction <= target and flat.flipped == 0
        if good and spacing == fine_mm and its == fine_iterations:
            formed[float(scale)] = (mesh, flat)
        # The relief as given, on the quick mesh: asked once (the plan's own mesh may
        # try 1.0 again while it closes in from below).
        if scale == 1.0 and reach_of is not None and "reach" not in given:
            given["reach"] = reach_of(hf, mesh, flat)
        return good

    lays_out = ok(1.0)
    reach_given = given.get("reach")
    within = reach_given is None or reach_given["within"]
    if lays_out and (within or not smooth_first or resmooth is None):
        return Fit(relief, relief, 1.0, smooth_mm, "forms as given", tried,
                   time.perf_counter() - t0, reach_given=reach_given)
    t1 = time.perf_counter()
    least, smooth_tried, smooth_reach = _second_lever(
        resmooth, smooth_mm, grid, s_min, s_max, target, iterations, reach_of,
        cap_mm=max(rows, cols) * hf.pixel_mm / 10.0)
    t2 = time.perf_counter()
    if least is not None and smooth_first:
        smoothed = resmooth(least)
        return Fit(relief, float(np.nanmax(smoothed.z) - np.nanmin(smoothed.z)), 1.0,
                   smooth_mm, _why(lays_out, s_max), tried, time.perf_counter() - t0, least,
                   smooth_tried, t2 - t1, applied_smooth_mm=least, reach_given=reach_given,
                   smooth_reach=smooth_reach, smoothed=smoothed)
    lo = 1.0 if lays_out else _lowered(ok, tried, hf, s_max, target, steps, grid, iterations,
                                        fine_mm, fine_steps, fine_iterations)
    reason = ("forms as given, but bends beyond the sheet's reach" if lays_out
              else _why(lays_out, s_max) if lo > 0
              else "no relief down to 2 % of the given one forms")
    return Fit(relief, relief * lo, float(lo), smooth_mm, reason, tried,
               time.perf_counter() - t0, least, smooth_tried, t2 - t1, formed.get(float(lo)),
               reach_given=reach_given, smooth_reach=smooth_reach)


def _why(lays_out, s_max):
    """Why the relief as given does not form, for the report and the warning."""
    if lays_out:
        return ("ridges and valleys narrower than the sheet can bend into (its curvature "
                "beyond what the layers' shrink can curl)")
    return ("slopes steeper than the material can form (at most %.0f degrees for a shrink "
            "of %.0f %%)" % (np.degrees(np.arccos(1.0 - s_max)), 100 * s_max))


def _lowered(ok, tried, hf, s_max, target, steps, grid, iterations, fine_mm, fine_steps,
             fine_iterations):
    """The first lever: the largest relief scale whose layout forms (0: none down to 2 %
    of the given one). A bound from the slopes, a bisection on the quick mesh, then a few
    solves on the plan's own mesh up from its answer."""
    lo, hi = 0.0, 1.0
    guess = min(slope_bound(hf, s_max), 0.9)
    while guess > 0.02:
        if ok(guess):
            lo = guess
            break
        hi, guess = guess, guess * 0.6
    if lo > 0:
        lo, hi = _close_in(ok, tried, lo, hi, target, steps, grid, iterations)
    if lo > 0 and fine_steps:
        # The coarse mesh errs on the safe side: look above its answer on the plan's own.
        top = min(1.0, hi * 1.3)
        if ok(top, fine_mm, fine_iterations):
            lo = top
        else:
            lo, hi = _close_in(ok, tried, lo, top, target, fine_steps - 1, fine_mm,
                               fine_iterations, area_a=0.0)
    return lo


def _second_lever(resmooth, smooth_mm, grid, s_min, s_max, target, iterations, reach_of,
                  cap_mm):
    """The least smoothing at which the relief as given lays out and (with ``reach_of``)
    lies within reach: (smooth_mm or None, [(smooth, invalid area, flipped)],
    [(smooth, reach p90)])."""
    smooth_tried, smooth_reach = [], []
    if resmooth is None:
        return None, smooth_tried, smooth_reach

    def forms(smooth):
        field = resmooth(smooth)
        mesh = build_grid_mesh(field, grid)
        flat = flatten_free(mesh, s_min, s_max, iterations=iterations)
        smooth_tried.append((smooth, float(flat.invalid_area_fraction), int(flat.flipped)))
        good = flat.invalid_area_fraction <= target and flat.flipped == 0
        if good and reach_of is not None:
            r = reach_of(field, mesh, flat)
            smooth_reach.append((smooth, r["p90"]))
            good = r["within"]
        return good

    return least_smoothing(forms, smooth_mm, cap_mm=cap_mm), smooth_tried, smooth_reach


def _close_in(ok, tried, a, b, target, steps, spacing, iterations, area_a=None):
    """Narrow the bracket ``a`` (forms) .. ``b`` (does not) by false position on the
    invalid area, which grows smoothly with the relief (the Illinois variant, so neither
    end sticks): a few solves land within a few per cent where bisection needs twice as
    many. An end's area is its last solve's at that scale, unless ``area_a`` is given
    (a bracket whose lower end was solved on another mesh). Returns the bracket."""
    def area(scale):
        return next((ar for sc, ar, _ in reversed(tried) if sc == scale), target)
    fa = (area(a) if area_a is None else area_a) - target
    fb = area(b) - target
    fa, fb, side, crept = min(fa, 0.0), max(fb, 1e-6), 0, 0
    for _ in range(steps):
        if b - a < 0.03 * b:
            break
        w = -fa / max(fb - fa, 1e-12)
        # A step up from near the lower end that formed: the area is flat there and
        # rises all at once above (a cone's flank passes the limit together), so bisect
        # rather than creep up (laid out closer to rest by mixed steps, a 60 mm cone's
        # area is 0.3 % at 0.77 of its relief, 1.3 % at 0.85 and 12 % at 0.87; crept up
        # twice, the fit stopped at 0.77).
        near = w < 0.25
        x = a + (b - a) * (0.5 if crept > 0 else min(max(w, 0.1), 0.9))
        if ok(x, spacing, iterations):
            crept = crept + 1 if near else 0
            a, fa = x, min(tried[-1][1] - target, 0.0)
            fb, side = (fb / 2 if side == -1 else fb), -1
        else:
            crept = 0
            b, fb = x, max(tried[-1][1] - target, 1e-6)
            fa, side = (fa / 2 if side == 1 else fa), 1
    return a, b
