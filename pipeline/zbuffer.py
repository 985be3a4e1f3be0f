"""Top surface of a triangle mesh sampled on a regular grid (a vectorised z-buffer).

Equivalent to casting one ray straight down per grid sample and keeping the
first hit, but done per triangle over its bounding box of samples, so cost
grows with covered area, not with rays x triangles.
"""

import numpy as np

# Candidate (triangle, sample) pairs handled per chunk; bounds peak memory (~100 MB).
_CHUNK_PAIRS = 2_000_000


def grid_shape(bounds_xy, pixel_mm):
    """(rows, cols) of the grid covering ``bounds_xy`` ((2, 2): [[xmin, ymin], [xmax, ymax]], mm)."""
    span = np.asarray(bounds_xy[1], float) - np.asarray(bounds_xy[0], float)
    cols, rows = (np.floor(span / pixel_mm + 1e-9).astype(int) + 1)
    return int(rows), int(cols)


def rasterize_top(vertices, faces, pixel_mm, colors=None):
    """Highest surface point over each grid sample.

    Parameters
    ----------
    vertices : (n, 3) float, mm
    faces : (m, 3) int
    pixel_mm : float
        Grid spacing. Sample (row, col) sits at x = xmin + col * pixel_mm,
        y = ymax - row * pixel_mm (row 0 north, as in HeightField).
    colors : (n, k) float or uint8, optional
        Per-vertex values interpolated at the winning hit (e.g. RGB).

    Returns
    -------
    z : (rows, cols) float, mm; NaN where no triangle covers the sample
    values : (rows, cols, k) float or None
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    xmin, ymin = v[:, :2].min(axis=0)
    xmax, ymax = v[:, :2].max(axis=0)
    rows, cols = grid_shape([[xmin, ymin], [xmax, ymax]], pixel_mm)
    # Triangle corners in grid units: u = column, w = row.
    u = (v[:, 0] - xmin) / pixel_mm
    w = (ymax - v[:, 1]) / pixel_mm
    tu, tw, tz = u[f], w[f], v[f, 2]
    det = (tu[:, 1] - tu[:, 0]) * (tw[:, 2] - tw[:, 0]) - (tu[:, 2] - tu[:, 0]) * (tw[:, 1] - tw[:, 0])
    keep = np.abs(det) > 1e-12  # vertical walls project to lines and never win
    f, tu, tw, tz, det = f[keep], tu[keep], tw[keep], tz[keep], det[keep]
    eps = 1e-7
    c0 = np.clip(np.ceil(tu.min(axis=1) - eps), 0, cols - 1).astype(np.int64)
    c1 = np.clip(np.floor(tu.max(axis=1) + eps), 0, cols - 1).astype(np.int64)
    r0 = np.clip(np.ceil(tw.min(axis=1) - eps), 0, rows - 1).astype(np.int64)
    r1 = np.clip(np.floor(tw.max(axis=1) + eps), 0, rows - 1).astype(np.int64)
    wc = np.maximum(c1 - c0 + 1, 0)
    count = wc * np.maximum(r1 - r0 + 1, 0)

    zbuf = np.full(rows * cols, -np.inf)
    kvals = None if colors is None else np.asarray(colors, dtype=np.float64)
    out = None if kvals is None else np.zeros((rows * cols, kvals.shape[1]))
    ends = np.cumsum(count)
    starts = ends - count
    lo = 0
    while lo < len(f):
        hi = int(np.searchsorted(ends, starts[lo] + _CHUNK_PAIRS, side="right"))
        hi = max(hi, lo + 1)
        sel = np.arange(lo, hi)
        t = np.repeat(sel, count[sel])
        k = np.arange(len(t)) - np.repeat(starts[sel] - starts[lo], count[sel])
        r = r0[t] + k // wc[t]
        c = c0[t] + k % wc[t]
        # Barycentric coordinates of the sample in its candidate triangle.
        du, dw = c - tu[t, 0], r - tw[t, 0]
        b1 = (du * (tw[t, 2] - tw[t, 0]) - dw * (tu[t, 2] - tu[t, 0])) / det[t]
        b2 = (dw * (tu[t, 1] - tu[t, 0]) - du * (tw[t, 1] - tw[t, 0])) / det[t]
        b0 = 1.0 - b1 - b2
        inside = (b0 >= -eps) & (b1 >= -eps) & (b2 >= -eps)
        t, r, c, b0, b1, b2 = t[inside], r[inside], c[inside], b0[inside], b1[inside], b2[inside]
        z = b0 * tz[t, 0] + b1 * tz[t, 1] + b2 * tz[t, 2]
        pix = r * cols + c
        # Highest hit per sample within the chunk, then against the buffer.
        order = np.lexsort((z, pix))
        last = np.r_[pix[order][1:] != pix[order][:-1], True]
        win = order[last]
        better = z[win] > zbuf[pix[win]]
        win = win[better]
        zbuf[pix[win]] = z[win]
        if out is not None:
            fv = f[t[win]]
            out[pix[win]] = (b0[win, None] * kvals[fv[:, 0]] + b1[win, None] * kvals[fv[:, 1]]
                             + b2[win, None] * kvals[fv[:, 2]])
        lo = hi
    zbuf[~np.isfinite(zbuf)] = np.nan
    z = zbuf.reshape(rows, cols)
    return z, None if out is None else out.reshape(rows, cols, -1)
