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
    """Round box sizes up a ladder of four steps per octave above 8 (<= 25 % waste),
    so boxes fall into few groups and the per-group overhead stays small."""
    n = np.asarray(n, dtype=np.int64)
    e = np.floor(np.log2(np.maximum(n, 2) - 1)).astype(np.int64) - 2
    step = np.left_shift(1, np.maximum(e, 0))
    return np.where(n <= 8, n, -(-n // step) * step)


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
    """Yield chunks of candidate pixels, boxes of one (rounded) size at a time.

    Yields (item, x0, y0, dx, dy, valid): ``item`` (c,) indexes the boxes, ``x0``,
    ``y0`` (c,) are their top-left pixels, ``dx``, ``dy`` (k,) the shared template
    of offsets and ``valid`` (c, k) bool is False where the template (rounded up)
    reaches past a box. Pixel of candidate (i, j): column x0[i] + dx[j], row y0[i] + dy[j].
    """
    item, x0, x1, y0, y1 = _split_bands(x0, x1, y0, y1)
    bw, bh = x1 - x0 + 1, y1 - y0 + 1
    rw, rh = _round_up(bw), _round_up(bh)
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
            valid = np.ones((len(sel), w * h), bool)
            if w * h > 1:
                valid = (dx < bw[sel, None]) & (dy < bh[sel, None])
            yield item[sel], x0[sel], y0[sel], dx, dy, valid


def _boxes(lo_x, hi_x, lo_y, hi_y, width, height):
    """Pixel boxes whose centres can fall in [lo, hi]; clipped to the image.

    Rows with NaN give garbage boxes: callers drop non-finite primitives.
    """
    with np.errstate(invalid="ignore"):
        x0 = np.clip(np.ceil(lo_x - 0.5), 0, width).astype(np.int64)
        x1 = np.clip(np.floor(hi_x - 0.5), -1, width - 1).astype(np.int64)
        y0 = np.clip(np.ceil(lo_y - 0.5), 0, height).astype(np.int64)
        y1 = np.clip(np.floor(hi_y - 0.5), -1, height - 1).astype(np.int64)
    return x0, x1, y0, y1


def _edge_functions(p):
    """Barycentric coordinates as linear functions of (x, y).

    p : (m, 3, 2) float, triangle corners in pixels.
    Returns (a, b, c) each (m, 3): ``w_k(x, y) = a_k x + b_k y + c_k``, with
    ``sum_k w_k = 1``; rows of degenerate triangles are NaN.
    """
    x0, x1, x2 = p[:, 0, 0], p[:, 1, 0], p[:, 2, 0]
    y0, y1, y2 = p[:, 0, 1], p[:, 1, 1], p[:, 2, 1]
    area2 = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(np.abs(area2) > 1e-12, 1.0 / area2, np.nan)[:, None]
    # w_k is the signed area of (x, corner k+1, corner k+2) over the full area.
    a = np.stack([y1 - y2, y2 - y0, y0 - y1], axis=1) * inv
    b = np.stack([x2 - x1, x0 - x2, x1 - x0], axis=1) * inv
    c = np.stack([x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0], axis=1) * inv
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
    xy = np.asarray(xy, dtype=np.float64)
    px, py = xy[:, 0][faces], xy[:, 1][faces]
    z = np.asarray(depth, dtype=np.float64)[faces]
    with np.errstate(invalid="ignore"):
        a, b, c = _edge_functions(np.stack([px, py], axis=2))
    ok = np.isfinite(a[:, 0]) & np.isfinite(z[:, 0] + z[:, 1] + z[:, 2])
    lo = lambda q: np.minimum(np.minimum(q[:, 0], q[:, 1]), q[:, 2])
    hi = lambda q: np.maximum(np.maximum(q[:, 0], q[:, 1]), q[:, 2])
    x0, x1, y0, y1 = _boxes(lo(px), hi(px), lo(py), hi(py), width, height)
    live = np.flatnonzero(ok & (x1 >= x0) & (y1 >= y0))
    if len(live) == 0:
        return face_id.reshape(shape)
    # Depth as a plane over the screen: z = az x + bz y + cz per face.
    az = a[:, 0] * z[:, 0] + a[:, 1] * z[:, 1] + a[:, 2] * z[:, 2]
    bz = b[:, 0] * z[:, 0] + b[:, 1] * z[:, 1] + b[:, 2] * z[:, 2]
    cz = c[:, 0] * z[:, 0] + c[:, 1] * z[:, 1] + c[:, 2] * z[:, 2]
    zmin, zmax = z[live].min(), z[live].max()
    zscale = (2 ** 31 - 2) / max(zmax - zmin, 1e-12)
    # Shared edges belong to both neighbours (no cracks); the depth test settles ties.
    eps = -1e-9
    best = np.full(height * width, np.iinfo(np.int64).max, dtype=np.int64)
    for it, bx, by, dx, dy, valid in _candidates(x0[live], x1[live], y0[live], y1[live]):
        f = live[it]
        xc, yc = bx + 0.5, by + 0.5
        w0 = (a[f, 0] * xc + b[f, 0] * yc + c[f, 0])[:, None] + a[f, 0, None] * dx + b[f, 0, None] * dy
        w1 = (a[f, 1] * xc + b[f, 1] * yc + c[f, 1])[:, None] + a[f, 1, None] * dx + b[f, 1, None] * dy
        valid &= (w0 >= eps) & (w1 >= eps) & (w0 + w1 <= 1 - eps)
        i, k = np.nonzero(valid)
        zq = (az[f[i]] * (xc[i] + dx[k]) + bz[f[i]] * (yc[i] + dy[k]) + (cz[f[i]] - zmin)) * zscale
        key = (np.clip(zq, 0, 2 ** 31 - 2).astype(np.int64) << 32) | f[i]
        np.minimum.at(best, (by[i] + dy[k]) * width + bx[i] + dx[k], key)
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
    # Coefficients once per face, then one gather per pixel.
    coef = np.concatenate(_edge_functions(np.asarray(xy, dtype=np.float64)[np.asarray(faces)]), axis=1)
    k = coef[face]
    w = k[:, 0:3] * (cols[:, None] + 0.5) + k[:, 3:6] * (rows[:, None] + 0.5) + k[:, 6:9]
    w = np.clip(np.nan_to_num(w, nan=1.0 / 3), 0.0, 1.0)
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
    fade32 = np.minimum(1.0, 2 * r).astype(np.float32)
    u32, v32, reach32 = u.astype(np.float32), v.astype(np.float32), reach.astype(np.float32)
    prio = np.zeros(s, np.int64) if priority is None else np.asarray(priority, np.int64)
    best = np.full(height * width, -1, dtype=np.int64)
    for it, bx, by, dx, dy, valid in _candidates(x0[live], x1[live], y0[live], y1[live]):
        g = live[it]
        ox = (bx + 0.5 - p0[g, 0]).astype(np.float32)[:, None] + dx.astype(np.float32)
        oy = (by + 0.5 - p0[g, 1]).astype(np.float32)[:, None] + dy.astype(np.float32)
        t = np.clip(ox * u32[g, 0, None] + oy * u32[g, 1, None], 0.0, 1.0)
        ex = ox - t * v32[g, 0, None]
        ey = oy - t * v32[g, 1, None]
        cov = np.clip(reach32[g, None] - np.sqrt(ex * ex + ey * ey), 0.0, 1.0) * fade32[g, None]
        i, k = np.nonzero(valid & (cov > 1.0 / 255))
        cq = np.round(cov[i, k] * 65535).astype(np.int64)
        key = (prio[g[i]] << 48) | (cq << 32) | g[i]
        np.maximum.at(best, (by[i] + dy[k]) * width + bx[i] + dx[k], key)
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
