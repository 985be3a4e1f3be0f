"""Vectorised software rasteriser (numpy only): z-buffered triangles, anti-aliased segments.

Pixel coordinates: ``x`` = column, ``y`` = row (row 0 at the top); pixel (row i, col j)
covers ``[j, j+1) x [i, i+1)`` and is sampled at its centre ``(j + 0.5, i + 0.5)``.

Both primitives work the same way: every primitive's clipped bounding box is
enumerated as candidate pixels, primitives with the same (rounded) box size share
one offset template so the per-pixel tests are plain array arithmetic, and the
winner per pixel is chosen with one ``np.minimum.at`` / ``np.maximum.at`` over a
packed int64 key (depth or coverage in the high bits, primitive id in the low
32 bits). No Python loop runs over primitives; the loops run over box-size groups
(a few dozen) and memory chunks.
"""

import numpy as np

# Candidate pixels evaluated per chunk: bounds the temporaries to ~100 MB.
_CHUNK = 1 << 21
# Boxes larger than this many pixels are cut into row bands, so one huge
# triangle does not produce a single enormous template.
_BAND = 1 << 14


def _round_up(n):
    """Round box sizes up a geometric ladder (<= 1/8 waste) to keep groups few."""
    n = np.asarray(n, dtype=np.int64)
    small = n <= 16
    e = np.floor(np.log2(np.maximum(n, 1) - 1e-9)).astype(np.int64) - 3
    step = np.left_shift(1, np.maximum(e, 0))
    big = -(-n // step) * step
    return np.where(small, n, big)


def _split_bands(x0, x1, y0, y1):
    """Cut boxes with more than ``_BAND`` pixels into row bands.

    Returns (item, x0, x1, y0, y1) with ``item`` the index of the original box.
    """
    bw = x1 - x0 + 1
    bh = y1 - y0 + 1
    rows = np.maximum(1, _BAND // np.maximum(bw, 1))
    nb = -(-bh // rows)
    item = np.repeat(np.arange(len(x0)), nb)
    k = np.arange(len(item)) - np.repeat(np.cumsum(nb) - nb, nb)
    yb0 = y0[item] + k * rows[item]
    yb1 = np.minimum(yb0 + rows[item] - 1, y1[item])
    return item, x0[item], x1[item], yb0, yb1


def _candidates(x0, x1, y0, y1):
    """Yield (item, x, y, valid) chunks: candidate pixels of boxes of one size.

    ``item`` (c,) indexes the boxes; ``x``, ``y`` (c, k) int are pixel columns
    and rows of each box's template; ``valid`` (c, k) bool is False where the
    template (rounded up) reaches past the box.
    """
    item, x0, x1, y0, y1 = _split_bands(x0, x1, y0, y1)
    rw = _round_up(x1 - x0 + 1)
    rh = _round_up(y1 - y0 + 1)
    key = rw * (1 << 20) + rh
    order = np.argsort(key, kind="stable")
    ks = key[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    ends = np.r_[starts[1:], len(ks)]
    for s, e in zip(starts, ends):
        w, h = int(ks[s] >> 20), int(ks[s] & ((1 << 20) - 1))
        dy, dx = np.divmod(np.arange(w * h, dtype=np.int64), w)
        per = max(1, _CHUNK // (w * h))
        for c in range(s, e, per):
            sel = order[c:min(e, c + per)]
            x = x0[sel, None] + dx
            y = y0[sel, None] + dy
            yield item[sel], x, y, (x <= x1[sel, None]) & (y <= y1[sel, None])


def _boxes(lo_x, hi_x, lo_y, hi_y, width, height):
    """Pixel boxes whose centres can fall in [lo, hi]; clipped to the image."""
    with np.errstate(invalid="ignore"):
        x0 = np.maximum(np.ceil(np.nan_to_num(lo_x - 0.5, nan=1e9)), 0).astype(np.int64)
        x1 = np.minimum(np.floor(np.nan_to_num(hi_x - 0.5, nan=-1e9)), width - 1).astype(np.int64)
        y0 = np.maximum(np.ceil(np.nan_to_num(lo_y - 0.5, nan=1e9)), 0).astype(np.int64)
        y1 = np.minimum(np.floor(np.nan_to_num(hi_y - 0.5, nan=-1e9)), height - 1).astype(np.int64)
    return x0, x1, y0, y1


def _edge_functions(p):
    """Barycentric coordinates as linear functions of (x, y).

    p : (m, 3, 2) float, triangle corners in pixels.
    Returns (a, b, c) each (m, 3): ``w_k(x, y) = a_k x + b_k y + c_k``, with
    ``sum_k w_k = 1``; rows of degenerate triangles are NaN.
    """
    x, y = p[..., 0], p[..., 1]
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)  # corner k+1
    xp, yp = np.roll(x, -2, axis=1), np.roll(y, -2, axis=1)  # corner k+2
    area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(np.abs(area2) > 1e-12, 1.0 / area2, np.nan)[:, None]
    # w_k is the signed area of (x, corner k+1, corner k+2) over the full area.
    a = (yn - yp) * inv
    b = (xp - xn) * inv
    c = (xn * yp - xp * yn) * inv
    return a, b, c


def rasterize_triangles(xy, depth, faces, shape):
    """Z-buffered coverage: which face is visible at each pixel.

    Both windings are drawn (no back-face culling).

    Parameters
    ----------
    xy : (n, 2) float, pixels
        Projected vertex positions (x = column, y = row).
    depth : (n,) float
        Distance from the viewer; smaller is nearer. Interpolated linearly in
        screen space (exact for orthographic views).
    faces : (m, 3) int
    shape : (height, width)

    Returns
    -------
    face_id : (height, width) int32
        Index of the nearest face covering each pixel centre, -1 where none.
    """
    height, width = shape
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    face_id = np.full(height * width, -1, dtype=np.int32)
    if len(faces) == 0:
        return face_id.reshape(shape)
    p = np.asarray(xy, dtype=np.float64)[faces]
    z = np.asarray(depth, dtype=np.float64)[faces]
    with np.errstate(invalid="ignore"):
        a, b, c = _edge_functions(p)
    ok = np.isfinite(a[:, 0]) & np.isfinite(p).all(axis=(1, 2)) & np.isfinite(z).all(axis=1)
    x0, x1, y0, y1 = _boxes(p[..., 0].min(1), p[..., 0].max(1), p[..., 1].min(1), p[..., 1].max(1),
                            width, height)
    live = np.flatnonzero(ok & (x1 >= x0) & (y1 >= y0))
    if len(live) == 0:
        return face_id.reshape(shape)
    # Depth as a plane over the screen: z = az x + bz y + cz per face.
    az, bz, cz = ((a * z).sum(1), (b * z).sum(1), (c * z).sum(1))
    zmin, zmax = z[live].min(), z[live].max()
    zscale = (2 ** 31 - 2) / max(zmax - zmin, 1e-12)
    eps = -1e-9  # shared edges belong to both neighbours; the depth test settles ties
    best = np.full(height * width, np.iinfo(np.int64).max, dtype=np.int64)
    for it, x, y, valid in _candidates(x0[live], x1[live], y0[live], y1[live]):
        f = live[it]
        xc = x + 0.5
        yc = y + 0.5
        w0 = a[f, 0, None] * xc + b[f, 0, None] * yc + c[f, 0, None]
        w1 = a[f, 1, None] * xc + b[f, 1, None] * yc + c[f, 1, None]
        valid &= (w0 >= eps) & (w1 >= eps) & (w0 + w1 <= 1 - eps)
        zq = (az[f, None] * xc + bz[f, None] * yc + (cz[f, None] - zmin)) * zscale
        i, k = np.nonzero(valid)
        zq = np.clip(zq[i, k], 0, 2 ** 31 - 2)
        key = (zq.astype(np.int64) << 32) | f[i]
        np.minimum.at(best, y[i, k] * width + x[i, k], key)
    hit = best != np.iinfo(np.int64).max
    face_id[hit] = (best[hit] & 0xFFFFFFFF).astype(np.int32)
    return face_id.reshape(shape)


def pixel_barycentrics(xy, faces, face_id):
    """Barycentric coordinates of the covered pixel centres in their faces.

    Parameters
    ----------
    xy : (n, 2) float, pixels
    faces : (m, 3) int
    face_id : (height, width) int, -1 for background (from :func:`rasterize_triangles`)

    Returns
    -------
    rows, cols : (k,) int
        Covered pixels.
    face : (k,) int
    w : (k, 3) float
        Barycentric weights of the face's corners (clipped to [0, 1], sum 1).
    """
    rows, cols = np.nonzero(face_id >= 0)
    face = face_id[rows, cols].astype(np.int64)
    p = np.asarray(xy, dtype=np.float64)[np.asarray(faces)[face]]
    a, b, c = _edge_functions(p)
    xc = cols[:, None] + 0.5
    yc = rows[:, None] + 0.5
    w = np.clip(np.nan_to_num(a * xc + b * yc + c, nan=1.0 / 3), 0.0, 1.0)
    w /= np.maximum(w.sum(1, keepdims=True), 1e-12)
    return rows, cols, face, w


def draw_segments(canvas, p0, p1, colors, width_px=1.0, priority=None):
    """Composite anti-aliased round-capped thick segments onto ``canvas`` in place.

    Each pixel takes the segment with the highest ``priority``, then the highest
    coverage, so a polyline's joints are seamless and neighbouring paths of
    different colours meet at a crisp line; the coverage (distance to the centre
    line against half the width, 1 px ramp) blends with what the canvas held.
    A zero-length segment draws a disc (markers).

    Parameters
    ----------
    canvas : (height, width, 3) float
        Modified in place (values 0-255).
    p0, p1 : (s, 2) float, pixels
        Segment end points (x = column, y = row).
    colors : (s, 3) or (3,) float/uint8
    width_px : float or (s,) float
        Full stroke width; below 1 px the stroke fades instead of thinning.
    priority : (s,) int in [0, 32767], optional

    Returns
    -------
    canvas
    """
    height, width = canvas.shape[:2]
    p0 = np.asarray(p0, dtype=np.float64).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=np.float64).reshape(-1, 2)
    s = len(p0)
    if s == 0:
        return canvas
    r = 0.5 * np.broadcast_to(np.asarray(width_px, dtype=np.float64), (s,))
    reach = r + 0.5
    lo = np.minimum(p0, p1) - reach[:, None]
    hi = np.maximum(p0, p1) + reach[:, None]
    x0, x1, y0, y1 = _boxes(lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], width, height)
    live = np.flatnonzero(np.isfinite(p0).all(1) & np.isfinite(p1).all(1) & (x1 >= x0) & (y1 >= y0))
    if len(live) == 0:
        return canvas
    v = p1 - p0
    vv = np.einsum("ij,ij->i", v, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(vv[:, None] > 1e-12, v / vv[:, None], 0.0)
    # float32 is ample at pixel scale and halves the memory traffic.
    fade32 = np.minimum(1.0, 2 * r).astype(np.float32)
    u32, v32, reach32 = u.astype(np.float32), v.astype(np.float32), reach.astype(np.float32)
    prio = np.zeros(s, np.int64) if priority is None else np.asarray(priority, np.int64)
    best = np.full(height * width, -1, dtype=np.int64)
    for it, x, y, valid in _candidates(x0[live], x1[live], y0[live], y1[live]):
        g = live[it]
        ox = x.astype(np.float32) + (0.5 - p0[g, 0, None]).astype(np.float32)
        oy = y.astype(np.float32) + (0.5 - p0[g, 1, None]).astype(np.float32)
        t = np.clip(ox * u32[g, 0, None] + oy * u32[g, 1, None], 0.0, 1.0)
        ex = ox - t * v32[g, 0, None]
        ey = oy - t * v32[g, 1, None]
        cov = np.clip(reach32[g, None] - np.sqrt(ex * ex + ey * ey), 0.0, 1.0) * fade32[g, None]
        i, k = np.nonzero(valid & (cov > 1.0 / 255))
        cq = np.round(cov[i, k] * 65535).astype(np.int64)
        key = (prio[g[i]] << 48) | (cq << 32) | g[i]
        np.maximum.at(best, y[i, k] * width + x[i, k], key)
    hit = np.flatnonzero(best >= 0)
    g = best[hit] & 0xFFFFFFFF
    cov = ((best[hit] >> 32) & 0xFFFF) / 65535.0
    col = np.broadcast_to(np.asarray(colors, dtype=np.float64), (s, 3))[g]
    flat = canvas.reshape(-1, 3)
    flat[hit] = cov[:, None] * col + (1 - cov[:, None]) * flat[hit]
    return canvas


def dash_segments(p0, p1, on_px, off_px):
    """Cut segments into dashes ``on_px`` long with ``off_px`` gaps (pixels).

    Returns (q0, q1, src): dash end points (d, 2) and the source segment of each.
    """
    p0 = np.asarray(p0, dtype=np.float64).reshape(-1, 2)
    p1 = np.asarray(p1, dtype=np.float64).reshape(-1, 2)
    length = np.linalg.norm(p1 - p0, axis=1)
    period = on_px + off_px
    n = np.maximum(1, np.ceil(length / period).astype(np.int64))
    src = np.repeat(np.arange(len(p0)), n)
    k = np.arange(len(src)) - np.repeat(np.cumsum(n) - n, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(length > 0, 1.0 / length, 0.0)[src]
    t0 = np.minimum(k * period * inv, 1.0)
    t1 = np.minimum((k * period + on_px) * inv, 1.0)
    d = (p1 - p0)[src]
    return p0[src] + t0[:, None] * d, p0[src] + t1[:, None] * d, src
