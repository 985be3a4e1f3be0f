"""Smooth only where the sheet cannot form the input: a local fit.

The global fit (:mod:`pipeline.layout.fit`) smooths the whole field as much as its
worst spot needs: the real tiles lost 6 mm of detail everywhere, also on gentle slopes
the sheet forms as given. Here each sample takes the least smoothing of a ladder
(:data:`LADDER_MM`) at which it lies within the material's limits:

- its slope at most the steepest a shrink of ``s_max`` forms, ``tan(acos(1 - s_max))``;
- its largest principal curvature at most :data:`pipeline.layout.reach.WITHIN` of the
  stack's limit ``c * (s_max - s_min) / h`` (:mod:`pipeline.layout.reach`, ``h`` the
  stack at the middle of the shrink range).

The levels are blended over ``blend_mm`` (a sample's level is the largest within that
distance, then Gaussian-averaged), and the field at a fractional level interpolates the
two smoothings beside it: detail is kept where it forms and removed where it does not,
without a seam. :meth:`LocalFit.at` caps the ladder at ``cap_mm``, so the fit's search
for the least smoothing that forms (:func:`pipeline.layout.fit.least_smoothing`) runs
over it as over the global one; samples that need more than the cap take the cap.
"""

import numpy as np
from scipy.ndimage import gaussian_filter, maximum_filter

from pipeline.geometry import HeightField
from pipeline.input.simplify import smooth
from pipeline.layout.reach import WITHIN, curvature_limit

LADDER_MM = (0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0)
BLEND_MM = 3.0


def slope_and_curvature(z, pixel_mm):
    """Per sample, the slope (rise over run) and the largest principal curvature
    magnitude (1/mm) of a height grid (rows, cols) mm; NaN outside."""
    gy, gx = np.gradient(z, pixel_mm)
    gyy, gyx = np.gradient(gy, pixel_mm)
    gxy, gxx = np.gradient(gx, pixel_mm)
    g2 = 1.0 + gx * gx + gy * gy
    # The Hessian over the metric: exact at a horizontal point, on the side of caution
    # on a slope (a graph's principal curvatures are at most this).
    half_sum = 0.5 * (gxx + gyy)
    root = np.sqrt(0.25 * (gxx - gyy) ** 2 + 0.25 * (gxy + gyx) ** 2)
    k = (np.abs(half_sum) + root) / g2
    return np.sqrt(g2 - 1.0), k


def limits(profile):
    """(steepest slope, largest curvature 1/mm the plan accepts) of a profile."""
    lim = profile.shrink_limits
    from pipeline.simulation.shell import thickness_for
    h = float(thickness_for(np.array([(lim.s_min + lim.s_max) / 2]), profile.shrink_curve,
                            profile.layers, profile.thickness_mm.min,
                            profile.thickness_mm.max)[0])
    k = float(curvature_limit(h, lim.s_min, lim.s_max, profile.curvature.bilayer_c))
    return float(np.tan(np.arccos(1.0 - lim.s_max))), WITHIN * k


def levels(z, pixel_mm, max_slope, max_curvature, ladder=LADDER_MM, measure_mm=1.0):
    """The ladder's fields and, per sample, the index of the least smoothing at which it
    forms (len(ladder) where none does): ([(rows, cols)], (rows, cols) int). Slopes and
    curvatures are measured at ``measure_mm`` at least (the sheet's mesh spacing: the
    samples' own noise is no feature the plan meshes)."""
    fields, need = [], np.full(z.shape, len(ladder), dtype=int)
    for i, s in enumerate(ladder):
        f = smooth(z, s / pixel_mm) if s > 0 else np.array(z, dtype=float)
        seen = f if s >= measure_mm else smooth(z, measure_mm / pixel_mm)
        slope, k = slope_and_curvature(seen, pixel_mm)
        ok = (slope <= max_slope) & (k <= max_curvature) & (need == len(ladder))
        need[ok] = i
        fields.append(f)
    return fields, need


def blended(fields, need, pixel_mm, cap_index, blend_mm=BLEND_MM):
    """The field whose level at each sample is ``need`` capped at ``cap_index``, spread to
    its neighbours within ``blend_mm`` and averaged over it: (z (rows, cols), level)."""
    inside = np.isfinite(fields[0])
    lev = np.minimum(need, cap_index).astype(float)
    reach_px = max(1, int(round(blend_mm / pixel_mm)))
    lev = maximum_filter(np.where(inside, lev, 0.0), size=2 * reach_px + 1)
    lev = gaussian_filter(lev, reach_px / 2.0)
    lo = np.clip(np.floor(lev).astype(int), 0, len(fields) - 1)
    hi = np.clip(lo + 1, 0, len(fields) - 1)
    t = lev - lo
    stack = np.stack(fields)
    rr, cc = np.indices(lev.shape)
    z = (1 - t) * stack[lo, rr, cc] + t * stack[hi, rr, cc]
    return np.where(inside, z, np.nan), np.where(inside, lev, np.nan)


class LocalFit:
    """The local fits of one field: its ladder is computed once, each cap blends it.

    hf : HeightField; max_slope, max_curvature : :func:`limits`."""

    def __init__(self, hf, max_slope, max_curvature, blend_mm=BLEND_MM, ladder=LADDER_MM,
                 measure_mm=1.0):
        self.hf, self.blend_mm, self.ladder = hf, blend_mm, ladder
        self.fields, self.need = levels(np.asarray(hf.z, dtype=float), hf.pixel_mm,
                                        max_slope, max_curvature, ladder, measure_mm)

    def at(self, cap_mm):
        """``hf`` smoothed where it does not form, at most ``cap_mm``, as given elsewhere."""
        cap = max([i for i, s in enumerate(self.ladder) if s <= cap_mm + 1e-9], default=0)
        z, _ = blended(self.fields, self.need, self.hf.pixel_mm, cap, self.blend_mm)
        return HeightField(z, self.hf.pixel_mm, color=self.hf.color, source=self.hf.source)

    def beyond_share(self):
        """The share of the footprint that does not form as given."""
        inside = np.isfinite(self.fields[0])
        return float((self.need[inside] > 0).mean())


def removed(given, fitted):
    """Where the fit changed the input: |fitted - given| (rows, cols) mm, NaN outside."""
    return np.abs(np.asarray(fitted.z, float) - np.asarray(given.z, float))
