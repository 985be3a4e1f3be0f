"""How close the simulated sheet comes to the file as dropped, not to the target planned.

The plan measures its sheet against the target it laid out, which after the fit is the
input smoothed or lowered; a person compares the sheet with the file they gave. The
report's ``fidelity`` section measures against that file, at the planned size, before
any smoothing or lowering (pits filled only where validation had to):

- ``mean_mm``, ``p90_mm``: each sheet point's distance to the input point it was
  planned for (same x, y; the input's height there), after a rigid fit of the sheet
  to those points, and the mean as a share of the longest diameter;
- ``relief_reached``: the sheet's relief (its height range as simulated, upright on
  its target) over the input's;
- ``right_way``, ``right_way_strong``: the share of the input's hills and valleys that
  the sheet curves the same way (the sign of the mean curvature), over the area where
  the input curves at all and where it curves strongly (the more curved half);
- ``curvature_slope``: the sheet's mean curvature regressed on the input's, point by
  point (1: kept in full, 0: flattened, below 0: turned over).

- ``bands``: the relief split in octaves of scale (Gaussian sigma, mm), and per octave
  how much of the file's relief there the target planned keeps and the sheet forms
  (the slope, through 0, of one's band on the other's; see :func:`bands`), and
  ``kept_from_mm``: the finest scale from which on the sheet keeps every octave of the
  file (:func:`kept_from`).

Curvatures are compared at the scale the sheet can resolve (a Gaussian of
``resolve_mm``: the tightest radius its stack can curl, at least two mesh spacings),
on the input's grid, away from the outline by twice that scale.
"""

import numpy as np
from scipy.ndimage import binary_erosion, map_coordinates
from scipy.spatial import Delaunay

from pipeline.input.simplify import smooth
from pipeline.simulation.forward import align

# Where the input curves "at all": above this share of its 95th-percentile curvature.
CURVES = 0.05
# The octaves the relief is split in (Gaussian sigma, mm): from the scale of the finest
# relief a sheet curls (:func:`resolve_mm`) to the broad shape of a 175 mm tile; what lies
# above the last is one more band.
BAND_EDGES_MM = (2.0, 4.0, 8.0, 16.0, 32.0)
# The grid the bands are taken on (mm, about; whole input pixels): half the finest
# edge. On the input's own 0.5 mm grid they took 0.7 s of a 175 mm plan.
BAND_PIXEL_MM = 1.0
# An octave of the file is kept where the sheet's has this much of it, and not more than
# its inverse (a sheet that overshoots a scale has not kept it either).
KEPT = 0.8


def heights_at(hf, xy):
    """The field's heights at plane points: xy (n, 2) mm -> (n,) mm, bilinear, NaN
    outside (nearest inside value at the outline's half-sample fringe)."""
    r, c = hf.rc(xy)
    z = np.asarray(hf.z, dtype=float)
    filled = np.where(np.isfinite(z), z, np.nanmean(z))
    out = map_coordinates(filled, [r, c], order=1, mode="nearest")
    near = map_coordinates(np.isfinite(z).astype(float), [r, c], order=1, mode="constant")
    return np.where(near > 0.5, out, np.nan)


def distances(sheet, target, given):
    """Per point, the sheet's distance to the input as given.

    sheet : (n, 3) mm, the simulated sheet; target : (n, 3) mm, the points it was planned
    for; given : HeightField, the input as given on the target's plane frame. Returns
    (aligned sheet (k, 3), given points (k, 3), distance (k,) mm) over the points inside
    the input's footprint."""
    target = np.asarray(target, dtype=float)
    z = heights_at(given, target[:, :2])
    keep = np.isfinite(z)
    points = np.column_stack([target[keep, :2], z[keep]])
    aligned, dist = align(np.asarray(sheet, dtype=float)[keep], points)
    return aligned, points, dist


def sheet_heights(aligned, hf):
    """The aligned sheet as heights on ``hf``'s grid: (rows, cols) mm, NaN outside its
    convex hull or the footprint."""
    rows, cols = hf.z.shape
    rr, cc = np.mgrid[0:rows, 0:cols]
    z = _linear(aligned[:, :2], aligned[:, 2], hf.xy(rr, cc).reshape(-1, 2))
    return np.where(np.isfinite(hf.z), z.reshape(rows, cols), np.nan)


def _linear(points, values, at):
    """Piecewise-linear interpolation of ``values`` ((n,)) at ``points`` ((n, 2)) over
    their Delaunay triangles, at ``at`` ((k, 2)): (k,), NaN outside the hull. What
    scipy.interpolate's LinearNDInterpolator does, whose import cost each plan 0.17 s."""
    tri = Delaunay(points)
    simplex = tri.find_simplex(at)
    inside = simplex >= 0
    T = tri.transform[simplex[inside]]                       # (k, 3, 2)
    b = np.einsum("kij,kj->ki", T[:, :2], at[inside] - T[:, 2])
    w = np.column_stack([b, 1.0 - b.sum(axis=1)])
    out = np.full(len(at), np.nan)
    out[inside] = np.einsum("ki,ki->k", values[tri.simplices[simplex[inside]]], w)
    return out


def mean_curvature(z, pixel_mm, sigma_mm):
    """Mean curvature (1/mm, > 0 where the surface is a valley, < 0 on a hill) of a
    height grid (rows, cols) mm smoothed ``sigma_mm``; NaN outside."""
    zs = smooth(np.asarray(z, dtype=float), sigma_mm / pixel_mm)
    gy, gx = np.gradient(zs, pixel_mm)
    norm = np.sqrt(1.0 + gx * gx + gy * gy)
    dyy, _ = np.gradient(gy / norm, pixel_mm)
    _, dxx = np.gradient(gx / norm, pixel_mm)
    return 0.5 * (dxx + dyy)


def agreement(h_input, h_sheet, mask):
    """How the sheet's curvature follows the input's over ``mask``: (share curving the
    same way where the input curves, the same where it curves strongly (the more curved
    half), slope of the sheet's on the input's through 0). NaN where nothing curves."""
    ok = mask & np.isfinite(h_input) & np.isfinite(h_sheet)
    hi, hs = h_input[ok], h_sheet[ok]
    if not len(hi):
        return float("nan"), float("nan"), float("nan")
    mag = np.abs(hi)
    curves = mag > CURVES * np.percentile(mag, 95)
    strong = mag >= np.median(mag[curves]) if curves.any() else curves
    same = np.sign(hi) == np.sign(hs)

    def share(where):
        return float(same[where].mean()) if where.any() else float("nan")
    slope = float((hi * hs).sum() / max((hi * hi).sum(), 1e-300))
    return share(curves), share(curves & strong), slope


def fidelity(sheet, target, given, diameter_mm, resolve_mm, planned=None):
    """The report's ``fidelity`` section (see the module's doc).

    sheet, target : (n, 3) mm, the simulated sheet and its planned points; given :
    HeightField, the input as given (validated, before smoothing or lowering) on the
    plan's grid; diameter_mm : the longest diameter; resolve_mm : the smallest feature
    scale the sheet can form (Gaussian sigma, mm); planned : (rows, cols) mm, the target
    planned on ``given``'s grid, for the ``bands`` (left out without it)."""
    aligned, points, dist = distances(sheet, target, given)
    relief_given = float(np.nanmax(given.z) - np.nanmin(given.z))
    # As simulated, i.e. aligned to its own target: aligned to the input a lowered sheet
    # tilts toward the input's slope, and its height range would count the tilt.
    relief_sheet = float(np.ptp(np.asarray(sheet, dtype=float)[:, 2]))
    h_sheet = sheet_heights(aligned, given)
    h_in = mean_curvature(given.z, given.pixel_mm, resolve_mm)
    h_out = mean_curvature(h_sheet, given.pixel_mm, resolve_mm)
    margin = max(1, int(np.ceil(2 * resolve_mm / given.pixel_mm)))
    inner = binary_erosion(np.isfinite(h_sheet), iterations=margin)
    right, strong, slope = agreement(h_in, h_out, inner)
    out = {"mean_mm": round(float(dist.mean()), 3),
            "p90_mm": round(float(np.percentile(dist, 90)), 3),
            "max_mm": round(float(dist.max()), 3),
            "mean_fraction": round(float(dist.mean() / max(diameter_mm, 1e-9)), 5),
            "relief_given_mm": round(relief_given, 2), "relief_sheet_mm": round(relief_sheet, 2),
            "relief_reached": round(relief_sheet / max(relief_given, 1e-9), 4),
            "right_way": _round(right), "right_way_strong": _round(strong),
            "curvature_slope": _round(slope), "resolve_mm": round(float(resolve_mm), 2)}
    if planned is not None:
        out["bands"] = bands(given.z, planned, h_sheet, given.pixel_mm, inner)
        out["kept_from_mm"] = kept_from(out["bands"])
    return out


def bands(given, target, sheet, pixel_mm, mask, edges=BAND_EDGES_MM):
    """What the target and the sheet make of each octave of the file's relief.

    given, target, sheet : (rows, cols) mm heights on one grid (NaN outside); mask :
    (rows, cols) bool, where to compare. Each band is the field smoothed at one edge
    less the field smoothed at the next (the last: smoothed at the last edge, less its
    mean). Returns one dict per band: ``from_mm``, ``to_mm`` (None for the last),
    ``given_rms_mm``, ``target_rms_mm``, ``sheet_rms_mm``, and the gains (slope through
    0 of one's band on the other's: 1 kept, 0 gone, < 0 turned over) ``target_gain``
    (target on file), ``sheet_gain`` (sheet on file) and ``formed_gain`` (sheet on
    target: what the sheet forms of what was planned)."""
    ok = mask & np.isfinite(given) & np.isfinite(target) & np.isfinite(sheet)
    f = max(1, int(round(BAND_PIXEL_MM / pixel_mm)))
    fields = [_block_mean(np.where(ok, z, np.nan), f) for z in (given, target, sheet)]
    ok = np.isfinite(fields[0])
    if not ok.any():
        return []
    split = [_octaves(z, pixel_mm * f, edges, ok) for z in fields]
    out = []
    for k in range(len(edges)):
        g, t, sh = (bands_[k] for bands_ in split)
        out.append({"from_mm": edges[k], "to_mm": edges[k + 1] if k + 1 < len(edges) else None,
                    "given_rms_mm": _round(_rms(g)), "target_rms_mm": _round(_rms(t)),
                    "sheet_rms_mm": _round(_rms(sh)), "target_gain": _round(_gain(t, g)),
                    "sheet_gain": _round(_gain(sh, g)), "formed_gain": _round(_gain(sh, t))})
    return out


def kept_from(octaves, kept=KEPT):
    """The finest band edge (mm) from which on the sheet keeps every octave of the file
    (:func:`bands`; its ``sheet_gain`` within ``kept`` and 1 / ``kept``), None where it
    keeps not even the broadest."""
    edge = None
    for band in reversed(octaves):
        gain = band["sheet_gain"]
        if gain is None or not kept <= gain <= 1.0 / kept:
            break
        edge = band["from_mm"]
    return edge


def _octaves(z, pixel_mm, edges, ok):
    """``z`` split in the bands of :func:`bands`, each as its values over ``ok``."""
    z = np.where(ok, z, np.nan)
    smoothed = [smooth(z, e / pixel_mm)[ok] for e in edges]
    out = [a - b for a, b in zip(smoothed[:-1], smoothed[1:])]
    return out + [smoothed[-1] - smoothed[-1].mean()]


def _block_mean(z, f):
    """``z`` ((rows, cols), NaN outside) averaged over blocks of ``f`` by ``f`` pixels,
    NaN where a block is not whole inside: (rows // f, cols // f)."""
    if f == 1:
        return z
    r, c = (z.shape[0] // f) * f, (z.shape[1] // f) * f
    blocks = z[:r, :c].reshape(r // f, f, c // f, f)
    return blocks.mean(axis=(1, 3))


def _rms(v):
    return float(np.sqrt(np.mean(v * v)))


def _gain(of, on):
    return float((of * on).sum() / (on * on).sum()) if (on * on).sum() > 0 else float("nan")


def _round(v):
    return None if not np.isfinite(v) else round(float(v), 4)


def resolve_mm(profile):
    """The smallest feature scale the sheet forms (Gaussian sigma, mm): the tightest radius
    its thinnest stack can curl (:func:`pipeline.layout.reach.curvature_limit`), at
    least two of its mesh spacings."""
    from pipeline.layout.reach import curvature_limit
    lim = profile.shrink_limits
    k = curvature_limit(profile.layers * profile.thickness_mm.min, lim.s_min, lim.s_max,
                        profile.curvature.bilayer_c)
    return float(max(1.0 / k, 2.0 * profile.mesh.grid_mm))


def of_plan(plan, profile):
    """The ``fidelity`` section of a :class:`pipeline.plan.Plan`: its simulated sheet
    against the input as validated (before the simplification and the fit)."""
    sim = plan.sim
    target = plan.mesh.vertices if sim.target is None else sim.target
    diameter = plan.report["heightfield"]["longest_diameter_mm"]
    given = plan.validated
    planned = plan.hf.z if plan.hf.z.shape == given.z.shape else None
    return fidelity(sim.vertices, target, given, diameter, resolve_mm(profile), planned)


def against_given(sheet, target, given):
    """The sheet beside the file as given, for the preview: (given points (n, 3) mm, the
    target's height where the file has none; the sheet rigidly fitted to them (n, 3);
    each point's distance (n,) mm)."""
    target = np.asarray(target, dtype=float)
    z = heights_at(given, target[:, :2])
    points = np.column_stack([target[:, :2], np.where(np.isfinite(z), z, target[:, 2])])
    return (points,) + align(np.asarray(sheet, dtype=float), points)
