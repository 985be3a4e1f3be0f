"""Vectorised software rasteriser (numpy only): z-buffered triangles, anti-aliased segments.

Pixel coordinates: ``x`` = column, ``y`` = row (row 0 at the top); pixel (row i, col j)
covers ``[j, j+1) x [i, i+1)`` and is sampled at its centre ``(j + 0.5, i + 0.5)``.

Both primitives work the same way: each is cut into one column span per pixel row it
reaches (exact for triangles, the bounding span for a segment's capsule), the spans are
expanded into pixels in chunks, and the winner per pixel is chosen with one
``np.minimum.at`` / ``np.maximum.at`` over a packed int64 key (depth or coverage in the
high bits, primitive id in the low 32 bits). A primitive's rows and a span's pixels are
consecutive: one ``np.repeat`` numbers the run each belongs to (:func:`_runs`), and
per-primitive values reach them by ``take`` on that (a ``take`` is about three times
faster than an ``np.repeat`` per value). Arithmetic runs on contiguous 1-D columns: on
(k, 2) or (k, 3) rows numpy loops a row at a time. No Python loop runs over
primitives; the loops run over memory chunks.
"""

import sys

import numpy as np

# Pixels evaluated per chunk: the temporaries (a few MB) stay in cache, which is faster
# than fewer, larger chunks.
_CHUNK = 1 << 17
# Primitives whose spans are worked out at once (a few MB of spans).
_BATCH = 1 << 14


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


def edge_functions(p):
    """Barycentric coordinates as linear functions of (x, y).

    p : (m, 3, 2) float, triangle corners in pixels.
    Returns (a, b, c) each (m, 3): ``w_k(x, y) = a_k x + b_k y + c_k``, with
    ``sum_k w_k = 1``; rows of degenerate triangles are NaN.
    """
    # Corner coordinates as contiguous columns: arithmetic on strided views is slower.
    x0, x1, x2, y0, y1, y2 = np.ascontiguousarray(np.asarray(p).transpose(2, 1, 0)).reshape(6, -1)
    area2 = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(np.abs(area2) > 1e-12, 1.0 / area2, np.nan)
    # w_k is the signed area of (x, corner k+1, corner k+2) over the full area.
    out = np.empty((3, len(inv), 3))
    for k, e in enumerate(((y1 - y2, y2 - y0, y0 - y1), (x2 - x1, x0 - x2, x1 - x0),
                           (x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0))):
        for j in range(3):
            np.multiply(e[j], inv, out=out[k, :, j])
    return out[0], out[1], out[2]


def _spans(a, b, c, live, x0, x1, y0, y1):
    """The pixel centres inside each triangle, as one column span per (face, row).

    a, b, c : (m, 3) edge functions (:func:`edge_functions`); live : faces to draw;
    x0..y1 : (m,) their clipped pixel boxes (the columns as float). Returns (face, row, first, last column),
    each (r,) int64, empty spans dropped. A centre on a shared edge belongs to both
    neighbours (the tolerance keeps rounding from opening cracks); depth settles ties.
    """
    # Edge k holds where a x + b y + c >= eps: x >= or <= (eps - c - b y) / a by the sign
    # of a, a line in y per face and edge (a horizontal edge, a = 0, only bounds the
    # rows, which the box already does). A triangle has one or two edges of each kind:
    # taking the first and the last of each makes it always two, and per row the span
    # is the larger of two lower bounds to the smaller of two upper ones.
    eps = -1e-9
    if len(live) and live[-1] - live[0] + 1 == len(live):
        live = slice(live[0], live[-1] + 1)  # all of a batch: views, not gathers
    al, bl, cl = a[live], b[live], c[live]
    with np.errstate(divide="ignore", invalid="ignore"):
        slope, icpt = (-bl / al).ravel(), ((eps - cl) / al).ravel()
    nrow = y1[live] - y0[live] + 1
    run, first = _runs(nrow)
    f = (np.arange(live.start, live.stop) if isinstance(live, slice) else live).take(run)
    y = np.arange(len(run)) + (y0[live] - first).take(run)
    yc = y + 0.5
    at = 3 * np.arange(len(nrow))
    bounds = []
    for side in (al > 0, al < 0):
        s0, s1, s2 = side[:, 0], side[:, 1], side[:, 2]
        # The first and the last edge of the kind (as argmax: 0 and 2 when there is none).
        for k in (at + np.where(s0, 0, np.where(s1, 1, np.where(s2, 2, 0))),
                  at + np.where(s2, 2, np.where(s1, 1, np.where(s0, 0, 2)))):
            # The bound's slope and intercept per face, then down the face's rows.
            bounds.append(slope.take(k).take(run) * yc + icpt.take(k).take(run))
    lo = np.maximum(bounds[0], bounds[1])
    hi = np.minimum(bounds[2], bounds[3])
    xa = np.maximum(np.ceil(lo - 0.5), x0.take(f)).astype(np.int64)
    xb = np.minimum(np.floor(hi - 0.5), x1.take(f)).astype(np.int64)
    keep = np.flatnonzero(xb >= xa)
    return f.take(keep), y.take(keep), xa.take(keep), xb.take(keep)


def _batched_spans(spans, live):
    """``spans(part)`` (-> (primitive, row, first, last column) as :func:`_spans`) of
    ``live`` in parts of :data:`_BATCH` primitives, each cut into :func:`_span_chunks`:
    the spans of all at once were a picture's peak (a 175 mm part's tool paths, a few
    hundred thousand segments and millions of spans: 160 MB)."""
    for k in range(0, len(live), _BATCH):
        yield from _span_chunks(*spans(live[k:k + _BATCH]))


def _span_chunks(*spans):
    """Split spans (as from :func:`_spans`) into runs of about ``_CHUNK`` pixels."""
    n = spans[3] - spans[2] + 1
    edges = np.searchsorted(np.cumsum(n), np.arange(_CHUNK, n.sum(), _CHUNK))
    for lo, hi in zip(np.r_[0, edges], np.r_[edges, len(n)]):
        if hi > lo:
            yield tuple(q[lo:hi] for q in spans)


def _runs(n):
    """Runs of ``n`` (k,) consecutive items: the run of each item (sum n,) and the index of
    each run's first item (k,), int64. Per-run values reach the items by ``take`` on the
    first: about three times faster than an ``np.repeat`` per value."""
    first = np.cumsum(n) - n
    return np.repeat(np.arange(len(n)), n), first


def _span_pixels(row_start, xa, xb):
    """Every pixel of the spans: flat index (row_start + column), column and span, each
    (p,) int64."""
    span, first = _runs(xb - xa + 1)
    k = np.arange(len(span))
    return k + (row_start + xa - first).take(span), k + (xa - first).take(span), span


def rasterize_triangles(xy, depth, faces, shape, edges=None, coverage=False):
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
    edges : (a, b, c), optional
        :func:`edge_functions` of ``xy[faces]``, when the caller has them.
    coverage : bool
        Only whether some face covers each pixel: no keys, no z-buffer.

    Returns
    -------
    face_id : (height, width) int32
        Index of the nearest face covering each pixel centre, -1 where none; with
        ``coverage`` a (height, width) bool, True where a face covers the centre.
    """
    height, width = shape
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    none = lambda: (np.zeros(shape, bool) if coverage else np.full(shape, -1, dtype=np.int32))
    if len(faces) == 0:
        return none()
    xy = np.asarray(xy, dtype=np.float64)
    px, py = xy[:, 0][faces], xy[:, 1][faces]
    z = np.asarray(depth, dtype=np.float64)[faces]
    if edges is None:
        with np.errstate(invalid="ignore"):
            edges = edge_functions(np.stack([px, py], axis=2))
    a, b, c = edges
    ok = np.isfinite(a[:, 0]) & np.isfinite(z[:, 0] + z[:, 1] + z[:, 2])
    lo = lambda q: np.minimum(np.minimum(q[:, 0], q[:, 1]), q[:, 2])
    hi = lambda q: np.maximum(np.maximum(q[:, 0], q[:, 1]), q[:, 2])
    x0, x1, y0, y1 = _boxes(lo(px), hi(px), lo(py), hi(py), width, height)
    live = np.flatnonzero(ok & (x1 >= x0) & (y1 >= y0))
    if len(live) == 0:
        return none()
    x0f, x1f = x0.astype(np.float64), x1.astype(np.float64)  # compared with float bounds
    spans = lambda part: _spans(a, b, c, part, x0f, x1f, y0, y1)
    # Depth as a plane over the screen: z = az x + bz y + cz per face, scaled to the
    # 31 bits it takes in the key.
    zmin, zmax = z[live].min(), z[live].max()
    flat = not zmax > zmin  # one depth (a 2-D layout): the lowest face index wins
    if coverage:
        hit = np.zeros(height * width, bool)
        for f, y, xa, xb in _batched_spans(spans, live):
            hit[_span_pixels(y * width, xa, xb)[0]] = True
        return hit.reshape(shape)
    if not flat:
        zscale = (2 ** 31 - 2) / max(zmax - zmin, 1e-12)
        # Sums written out: a reduction along a 3-long axis runs a loop per face.
        az, bz, cz = ((q[:, 0] * z[:, 0] + q[:, 1] * z[:, 1] + q[:, 2] * z[:, 2]) * zscale
                      for q in (a, b, c))
        cz -= zmin * zscale
    best = np.full(height * width, np.iinfo(np.int64).max, dtype=np.int64)
    for f, y, xa, xb in _batched_spans(spans, live):
        pix, x, span = _span_pixels(y * width, xa, xb)
        key = f.take(span)
        if not flat:
            zrow = bz[f] * (y + 0.5) + cz[f]
            zq = zrow.take(span) + az[f].take(span) * (x + 0.5)
            key |= np.clip(zq, 0, 2 ** 31 - 2).astype(np.int64) << 32
        np.minimum.at(best, pix, key)
    # The face is the key's low 32 bits; where none won they are all ones: -1 as int32.
    # Read in place as the int32 half of each key (one strided copy, not two passes).
    low = best.view(np.int32)[0 if sys.byteorder == "little" else 1::2]
    return np.ascontiguousarray(low).reshape(shape)


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
    coef = np.concatenate(edge_functions(np.asarray(xy, dtype=np.float64)[np.asarray(faces)]),
                          axis=1)
    k = coef[face]
    w = k[:, 0:3] * (cols[:, None] + 0.5) + k[:, 3:6] * (rows[:, None] + 0.5) + k[:, 6:9]
    w = np.clip(np.nan_to_num(w, nan=1.0 / 3), 0.0, 1.0)
    w /= np.maximum(w.sum(1, keepdims=True), 1e-12)
    return rows, cols, face, w


def face_planes(xy, faces, values, edges=None):
    """Per-vertex values as linear functions of the pixel position within each face.

    Parameters
    ----------
    xy : (n, 2) float, pixels
    faces : (m, 3) int
    values : (k, n) float
        One row per value.
    edges : (a, b, c), optional
        :func:`edge_functions` of ``xy[faces]``, when the caller has them.

    Returns
    -------
    (k, 3, m) float32: value ``j`` at pixel (x, y) of face ``f`` is
    ``P[j, 0, f] * x + P[j, 1, f] * y + P[j, 2, f]`` (exact inside the face, NaN for
    degenerate faces). One gather per pixel then replaces the barycentric weights
    and the three corner gathers of :func:`pixel_barycentrics`; each coefficient is a
    contiguous row, so the gathers and the arithmetic on them run on contiguous arrays.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    a, b, c = edge_functions(np.asarray(xy, dtype=np.float64)[faces]) if edges is None else edges
    vt = np.ascontiguousarray(values, dtype=np.float64)
    q = [vt[:, faces[:, j]] for j in range(3)]  # (k, m) per corner
    out = np.empty((len(vt), 3, len(faces)), np.float32)
    for i, e in enumerate((a, b, c)):
        e0, e1, e2 = (np.ascontiguousarray(e[:, j]) for j in range(3))
        out[:, i] = e0 * q[0] + e1 * q[1] + e2 * q[2]
    return out


def _capsule_spans(px0, py0, vx0, vy0, reach, live, x0, x1, y0, y1):
    """Column spans per (segment, row) holding every pixel centre within ``reach`` of
    the segment (slightly more at diagonal ends: the capsule's bounding span).

    px0, py0, vx0, vy0 : (s,) start and direction (p1 - p0), pixels; reach : (s,) px;
    live : segments to draw; x0..y1 : (s,) their clipped pixel boxes (the columns as
    float32). Returns (segment, row, first, last column), each (r,) int64, empty spans
    dropped.

    float32 is enough (half the memory traffic): a centre just outside a span is at
    least ``reach`` from the segment, so one that rounding moves across the span's end
    is within a thousandth of a pixel of that, and its coverage rounds to nothing.
    """
    nrow = y1[live] - y0[live] + 1
    run, first = _runs(nrow)
    g = live.take(run)
    y = np.arange(len(run)) + (y0[live] - first).take(run)
    # The stretch of the centre line within reach of the row, widened by reach.
    py, vy, px, vx, rg = (q.astype(np.float32, copy=False).take(g)
                          for q in (py0, vy0, px0, vx0, reach))
    yc = y.astype(np.float32) + np.float32(0.5)
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = np.where(vy != 0, (yc - rg - py) / vy, np.float32(0))
        tb = np.where(vy != 0, (yc + rg - py) / vy, np.float32(1))
    xa = px + np.clip(np.minimum(ta, tb), np.float32(0), np.float32(1)) * vx
    xb = px + np.clip(np.maximum(ta, tb), np.float32(0), np.float32(1)) * vx
    lo = np.minimum(xa, xb) - rg
    hi = np.maximum(xa, xb) + rg
    xa = np.maximum(np.ceil(lo - 0.5), x0.take(g)).astype(np.int64)
    xb = np.minimum(np.floor(hi - 0.5), x1.take(g)).astype(np.int64)
    keep = np.flatnonzero(xb >= xa)
    return g.take(keep), y.take(keep), xa.take(keep), xb.take(keep)


def draw_segments(canvas, p0, p1, colors, width_px=1.0, priority=None):
    """Composite anti-aliased round-capped thick segments onto ``canvas`` in place.

    Each pixel takes the segment with the highest ``priority``, then the highest
    coverage, so a polyline's joints are seamless and neighbouring paths of
    different colours meet at a crisp line; the coverage (distance to the centre
    line against half the width, 1 px ramp) blends with what the canvas held.
    A zero-length segment draws a disc (markers).

    Parameters
    ----------
    canvas : (height, width, 3) float, C-contiguous
        Modified in place (values 0-255); float32 halves the memory traffic.
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
    # Contiguous coordinate columns: arithmetic on (s, 2) rows loops two values at a time.
    px0, py0, px1, py1 = (np.ascontiguousarray(q) for q in (p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1]))
    x0, x1, y0, y1 = _boxes(np.minimum(px0, px1) - reach, np.maximum(px0, px1) + reach,
                            np.minimum(py0, py1) - reach, np.maximum(py0, py1) + reach,
                            width, height)
    live = np.flatnonzero(np.isfinite(px0 + py0 + px1 + py1) & (x1 >= x0) & (y1 >= y0))
    if len(live) == 0:
        return canvas
    vx, vy = px1 - px0, py1 - py0
    vv = vx * vx + vy * vy
    with np.errstate(divide="ignore", invalid="ignore"):
        ux, uy = (np.where(vv > 1e-12, q / vv, 0.0) for q in (vx, vy))
    fade = np.minimum(1.0, 2 * r)
    prio = np.zeros(s, np.int64) if priority is None else np.asarray(priority, np.int64)
    base = (prio << 48) | np.arange(s)
    # Per-segment values as float32 columns, gathered per span then per pixel.
    cols = {k: q.astype(np.float32) for k, q in
            dict(qx=0.5 - px0, qy=0.5 - py0, ux=ux, uy=uy, vx=vx, vy=vy, reach=reach,
                 fade=fade).items()}
    faded = bool((fade < 1).any())
    spans_at = [px0.astype(np.float32), py0.astype(np.float32), cols["vx"], cols["vy"],
                cols["reach"]]
    cols_f32 = x0.astype(np.float32), x1.astype(np.float32)  # compared with float32 bounds
    # One width for all (the usual case): its reach is one number, not gathered per pixel.
    reach1 = cols["reach"][0] if np.ndim(width_px) == 0 else None
    # Only the rows the segments reach: markers and short strokes need no full-canvas pass.
    top = int(y0[live].min())
    # 0 where none: every key is above it (its coverage, at least 257 of 65535, sits in
    # bits 32-47), and zeros need no pass to fill.
    best = np.zeros((int(y1[live].max()) + 1 - top) * width, dtype=np.int64)
    for g, y, xa, xb in _batched_spans(
            lambda part: _capsule_spans(*spans_at, part, *cols_f32, y0, y1), live):
        pix, x, span = _span_pixels((y - top) * width, xa, xb)
        rep = lambda k: cols[k].take(g).take(span)
        # Offsets from p0 in float32 (small numbers); t the nearest point's position.
        ox = x.astype(np.float32) + rep("qx")
        oy = (y.astype(np.float32) + cols["qy"].take(g)).take(span)
        t = np.clip(ox * rep("ux") + oy * rep("uy"), 0.0, 1.0)
        ex = ox - t * rep("vx")
        ey = oy - t * rep("vy")
        reach_px = rep("reach") if reach1 is None else reach1
        cov = np.clip(reach_px - np.sqrt(ex * ex + ey * ey), 0.0, 1.0)
        if faded:
            cov *= rep("fade")
        sel = np.flatnonzero(cov > 1.0 / 255)
        cq = np.round(cov[sel] * 65535).astype(np.int64)
        np.maximum.at(best, pix.take(sel), base.take(g).take(span.take(sel)) | (cq << 32))
    col = np.ascontiguousarray(np.broadcast_to(np.asarray(colors, canvas.dtype), (s, 3)))
    _blend(canvas, top, best, col)
    return canvas


def _blend(canvas, top, best, col):
    """Blend the winners ``best`` (packed keys of :func:`draw_segments`, 0 where none,
    rows from ``top`` on) into ``canvas``, a band of rows of about ``_CHUNK`` pixels at a
    time: the whole picture's at once held six colour arrays of every pixel drawn (a 175
    mm part's tool paths: 130 MB, the plan's peak)."""
    width = canvas.shape[1]
    flat = canvas.reshape(-1, 3)
    band = max(1, _CHUNK // width) * width
    planes = [np.ascontiguousarray(col[:, c]) for c in range(3)]
    for k in range(0, len(best), band):
        key = best[k:k + band]
        hit = key > 0
        o = (top * width + k)
        if np.count_nonzero(hit) * 4 > len(key):
            # Mostly drawn (tool paths, the stress layout): blending every pixel of the
            # band in place beats gathering and scattering the drawn ones. Where nothing
            # won, the key is 0: coverage 0 (of segment 0), and the pixel keeps its value
            # exactly. A channel at a time: the coverage broadcast over three channels makes
            # numpy loop per pixel.
            cov = ((key >> 32) & 0xFFFF).astype(canvas.dtype) / 65535
            seg = key & 0xFFFFFFFF
            for c in range(3):
                old = flat[o:o + len(key), c]
                old += cov * (planes[c].take(seg) - old)
            continue
        idx = np.flatnonzero(hit)
        key = key[idx]
        cov = ((key >> 32) & 0xFFFF).astype(canvas.dtype)[:, None] / 65535
        idx += o
        old = get_pixels(canvas, idx)
        set_pixels(canvas, idx, old + cov * (col.take(key & 0xFFFFFFFF, axis=0) - old))


def _pixel_items(canvas):
    """(h, w, 3) C-contiguous canvas -> (h * w,) view with one opaque item per pixel:
    gathering and scattering whole pixels as 1-D items is several times faster than
    fancy-indexing rows of a 2-D array."""
    if not canvas.flags.c_contiguous:
        raise ValueError("the canvas must be C-contiguous")
    return canvas.reshape(-1).view(np.dtype((np.void, 3 * canvas.itemsize)))


def get_pixels(canvas, index):
    """The colours (k, 3) of the pixels at flat ``index`` (k,) of an (h, w, 3) canvas."""
    return _pixel_items(canvas)[index].view(canvas.dtype).reshape(-1, 3)


def set_pixels(canvas, index, rgb):
    """Set the pixels at flat ``index`` (k,) of an (h, w, 3) canvas to ``rgb`` (k, 3)."""
    rgb = np.ascontiguousarray(rgb, dtype=canvas.dtype)
    _pixel_items(canvas)[index] = rgb.view(_pixel_items(canvas).dtype).reshape(-1)


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
