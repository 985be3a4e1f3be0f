"""How high a height field can be and still form: the largest relief the material allows.

A sheet that loses at most ``s_max`` of its length in one direction cannot form slopes
much steeper than ``acos(1 - s_max)`` (about 49 degrees for 34 %), nor regions that
must shrink in two directions at once. Real elevation data is drawn with 20-40x
vertical exaggeration, and its cliffs and scarps exceed that: a slightly lower relief
prints, the asked-for one does not.

:func:`fit_height` finds the largest height scale at which the free-direction layout
leaves at most ``target`` of the sheet outside the admissible set, with no flips: a
bound from the slopes, then a bisection of quick layout solves on a coarse mesh.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import HeightField
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
                "sidecar_height_mm": self.sidecar_height_mm()}

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
        if self.min_smooth_mm is None:
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
               iterations=100, steps=3, fine_mm=1.0, fine_steps=6, fine_iterations=200,
               resmooth=None):
    """The largest relief scale (<= 1) at which ``hf`` forms with the free layout.

    hf : validated HeightField; grid_mm : the search's mesh spacing (default: an 80th of
    the field's longest side, at least 2 mm: coarser than the plan's, and on the safe
    side of it); steps : bisection solves after the bounds on that mesh; fine_mm,
    fine_steps, fine_iterations : then a few on the plan's own mesh spacing and
    iterations, up from the coarse answer, so the fit is the largest relief the plan
    forms, not a coarse mesh's. resmooth : callable(smooth_mm) -> HeightField; where
    given and the relief does not form, :func:`least_smoothing` looks for the second
    lever (capped at a twentieth of the field's longest side).
    Returns :class:`Fit` (``applied_scale`` is the fitted scale; the caller decides
    whether to apply it).
    """
    t0 = time.perf_counter()
    z = np.asarray(hf.z, dtype=float)
    relief = float(np.nanmax(z) - np.nanmin(z))
    rows, cols = z.shape
    grid = grid_mm or max(2.0, max(rows, cols) * hf.pixel_mm / 80.0)
    tried, formed = [], {}

    def ok(scale, spacing=grid, its=iterations):
        mesh = build_grid_mesh(scaled(hf, scale), spacing)
        flat = flatten_free(mesh, s_min, s_max, iterations=its)
        tried.append((float(scale), float(flat.invalid_area_fraction), int(flat.flipped)))
        good = flat.invalid_area_fraction <= target and flat.flipped == 0
        if good and spacing == fine_mm and its == fine_iterations:
            formed[float(scale)] = (mesh, flat)
        return good

    if ok(1.0):
        return Fit(relief, relief, 1.0, smooth_mm, "forms as given", tried,
                   time.perf_counter() - t0)
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
    reason = ("slopes steeper than the material can form (at most %.0f degrees for a shrink "
              "of %.0f %%)" % (np.degrees(np.arccos(1.0 - s_max)), 100 * s_max)
              if lo > 0 else "no relief down to 2 % of the given one forms")
    t1, least, smooth_tried = time.perf_counter(), None, []
    if resmooth is not None:
        def forms(smooth):
            flat = flatten_free(build_grid_mesh(resmooth(smooth), grid), s_min, s_max,
                                iterations=iterations)
            smooth_tried.append((smooth, float(flat.invalid_area_fraction), int(flat.flipped)))
            return flat.invalid_area_fraction <= target and flat.flipped == 0
        least = least_smoothing(forms, smooth_mm, cap_mm=max(rows, cols) * hf.pixel_mm / 20.0)
    t2 = time.perf_counter()
    return Fit(relief, relief * lo, float(lo), smooth_mm, reason, tried, t2 - t0, least,
               smooth_tried, t2 - t1, formed.get(float(lo)))


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
        # Two steps up from near the lower end that both formed: the area is flat there
        # and rises all at once above (a cone's flank passes the limit together), so
        # bisect rather than creep up.
        near = w < 0.25
        x = a + (b - a) * (0.5 if crept > 1 else min(max(w, 0.1), 0.9))
        if ok(x, spacing, iterations):
            crept = crept + 1 if near else 0
            a, fa = x, min(tried[-1][1] - target, 0.0)
            fb, side = (fb / 2 if side == -1 else fb), -1
        else:
            crept = 0
            b, fb = x, max(tried[-1][1] - target, 1e-6)
            fa, side = (fa / 2 if side == 1 else fa), 1
    return a, b
