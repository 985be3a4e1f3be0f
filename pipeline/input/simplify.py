"""Simplify a height field's topology to what the sheet can form (see notes/real-terrain.md).

Real terrain has hundreds of peaks a few millimetres across; every peak is a
cone region and every saddle a polygon region with its own traces, yet six
layers of 0.1-0.45 mm paths with at most ~34 % shrink cannot form them. So,
before meshing:

1. smooth at ``smooth_mm`` (Gaussian sigma, normalised convolution so the
   NaN outside the footprint does not leak in),
2. cut every interior peak whose prominence (height above the saddle where it
   joins higher ground or the footprint edge) is below ``min_prominence_mm``
   down to that saddle: a depth-limited depression fill of the negated field,
   with an epsilon slope up toward the saddle so no cut top is exactly flat,
3. fill the pits smoothing may have closed (full fill, epsilon slope down).

Peaks and prominences are measured on the smoothed field.
"""

import numpy as np
from scipy.ndimage import gaussian_filter

from pipeline.geometry import HeightField
from pipeline.input.validate import EPS_MM, Grid, fill_depressions

# Removed peaks listed individually in the report (all are counted).
MAX_LISTED = 50


def smooth(z, sigma_px):
    """Footprint-aware Gaussian smoothing (normalised convolution).

    z : (rows, cols) float, mm, NaN outside. sigma_px : float, pixels.
    Returns (rows, cols) float with the same footprint.
    """
    fp = np.isfinite(z)
    if sigma_px <= 0:
        return z.copy()
    num = gaussian_filter(np.where(fp, z, 0.0), sigma_px, mode="constant")
    den = gaussian_filter(fp.astype(float), sigma_px, mode="constant")
    out = np.full(z.shape, np.nan)
    out[fp] = num[fp] / den[fp]
    return out


def interior_maxima(z):
    """(rows, cols) indices of interior strict local maxima (all 8 neighbours in the footprint)."""
    fp = np.isfinite(z)
    g = Grid(fp)
    v = z[fp]
    inner = ~g.boundary
    vn = g.neighbour_values(v, outside=np.inf)
    peak = inner & (vn < v[:, None]).all(axis=1)
    return g.rows[peak], g.cols[peak]


def simplify(hf, min_prominence_mm, smooth_mm, eps_mm=EPS_MM):
    """Smooth, cut low peaks to their saddles, refill pits.

    Parameters
    ----------
    hf : HeightField, validated (one piece, pits filled)
    min_prominence_mm : float
        Interior peaks less prominent than this are removed (0 keeps all).
    smooth_mm : float
        Gaussian sigma in mm (0 = no smoothing).

    Returns
    -------
    hf : HeightField
    report : dict ``peaks_before``, ``peaks_after`` (interior strict maxima),
        ``removed_peaks`` (the ``MAX_LISTED`` most prominent: {x_mm, y_mm,
        prominence_mm}), ``removed_count`` (all), ``max_change_mm`` (total),
        ``max_smoothing_change_mm`` (of which smoothing alone),
        ``refilled_volume_mm3``, ``refill_max_mm``, ``smooth_mm``,
        ``min_prominence_mm``, ``unresolved_flat_cells``
    """
    z = hf.z
    fp = hf.footprint
    zs = smooth(z, smooth_mm / hf.pixel_mm)
    removed = np.zeros((0, 4))
    cut = zs
    unresolved = 0
    if min_prominence_mm > 0:
        # Strictly below the threshold: a peak exactly that prominent stays.
        limit = np.nextafter(min_prominence_mm, -np.inf)
        neg, info = fill_depressions(-zs, limit, eps_mm)
        cut = -neg
        ev = info["events"]
        removed = ev[ev[:, 3] > 0]
        unresolved += info["unresolved"]
        g = info["grid"]
    out, info2 = fill_depressions(cut, np.inf, eps_mm)
    unresolved += info2["unresolved"]
    refill = out[fp] - cut[fp]
    listed = removed[:MAX_LISTED]
    peaks = []
    if len(listed):
        cells = listed[:, 0].astype(int)
        xy = hf.xy(g.rows[cells], g.cols[cells])
        peaks = [{"x_mm": float(p[0]), "y_mm": float(p[1]), "prominence_mm": float(d)}
                 for p, d in zip(xy, listed[:, 2])]
    report = {
        "peaks_before": int(len(interior_maxima(z)[0])),
        "peaks_after": int(len(interior_maxima(out)[0])),
        "removed_peaks": peaks,
        "removed_count": int(len(removed)),
        "max_change_mm": float(np.abs(out[fp] - z[fp]).max(initial=0.0)),
        "max_smoothing_change_mm": float(np.abs(zs[fp] - z[fp]).max(initial=0.0)),
        "refilled_volume_mm3": float(refill.sum() * hf.pixel_mm ** 2),
        "refill_max_mm": float(refill.max(initial=0.0)),
        "smooth_mm": float(smooth_mm),
        "min_prominence_mm": float(min_prominence_mm),
        "unresolved_flat_cells": int(unresolved),
    }
    return HeightField(out, hf.pixel_mm, color=hf.color, source=hf.source), report
