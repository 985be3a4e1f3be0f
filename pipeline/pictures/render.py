"""The pictures of a plan: stress layout, 3-D preview, tool paths (the input: :mod:`pipeline.pictures.hfimage`).

numpy + Pillow only (no display, no matplotlib); arrays in, ``PIL.Image`` out.
Drawing is vectorised in :mod:`pipeline.pictures.raster`; legends and bars in
:mod:`pipeline.pictures.figure`. Top views (stress, tool paths, height field) put +y
(north) up and record their mm-to-pixel map in ``image.info``:
``px_per_mm`` and ``origin_px`` (the pixel position of x = y = 0 mm), so a
caller can overlay or hit-test in millimetres.
"""

import numpy as np
from PIL import Image, ImageDraw

from pipeline.pictures.figure import (INK, INVALID_HIGH, INVERTED, INVALID_LOW, MUTED, WHITE, colorbar, colormap,
                             counted, extent, font, fmt_number, framed, nice_ceil, scale_bar,
                             stat_lines, swatch, text_size, to_image)
from pipeline.geometry import edge_index, edge_lengths, face_areas
from pipeline.printable import SIGMA_TOL
from pipeline.pictures.raster import dash_segments, draw_segments, rasterize_triangles
from pipeline.pictures.shading import camera_basis, project, shaded_view, view_fit

__all__ = ["colormap", "stress_image", "preview_image", "toolpath_image", "montage", "shaded_view"]

START_COLOR = (40, 185, 80)
TRAVEL_COLOR = (110, 110, 118)
DRY_COLOR = (25, 25, 25)


class _Plan:
    """Top-view map mm -> px: x to the right, +y (north) up, ``pad`` px margin."""

    def __init__(self, lo, hi, px_per_mm, pad):
        self.s = float(px_per_mm)
        self.w = int(np.ceil((hi[0] - lo[0]) * self.s)) + 2 * pad
        self.h = int(np.ceil((hi[1] - lo[1]) * self.s)) + 2 * pad
        self.ox = pad - lo[0] * self.s
        self.oy = pad + hi[1] * self.s

    def px(self, xy):
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([self.ox + self.s * xy[..., 0], self.oy - self.s * xy[..., 1]], axis=-1)

    def tag(self, img, body_xy):
        img.info["px_per_mm"] = self.s
        img.info["origin_px"] = (body_xy[0] + self.ox, body_xy[1] + self.oy)
        return img


# Pictures of small parts are drawn no finer than this: a 0.5 mm path is then 8 px wide,
# finer shows nothing more of it, and the drawing time grows with the pixels (a 15 mm
# dome's four pictures took 2.8 s at 1400 px on the longest side, most of its plan).
MAX_PX_PER_MM = 16.0
# The preview's panels: this fine up to 760 px each, and at least 480 px for their labels.
PREVIEW_PX_PER_MM = 8.0
PREVIEW_PANEL_PX = (480, 760)


def _scale(extent_mm, px_per_mm, max_px, long_px=1400):
    """px/mm: the requested one (or one giving ``long_px`` on the longest side, at most
    ``MAX_PX_PER_MM``), capped by ``max_px``."""
    ext = max(float(extent_mm), 1e-6)
    s = px_per_mm if px_per_mm else min(long_px / ext, MAX_PX_PER_MM)
    return min(s, max_px / ext)


def _boundary_edges(faces):
    """Edges used by exactly one face: (k, 2) int."""
    a = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    b = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    n = int(faces.max()) + 1 if len(faces) else 1
    # Each edge's key from its smaller then larger end (np.sort along a 2-long axis sorts
    # a row at a time); 1-D unique is far faster than axis=0.
    key, count = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)
    key = key[count == 1]
    return np.stack([key // n, key % n], axis=1)


def _pct(v):
    return fmt_number(100 * v, 0.1)


def _invalid_texts(n_high, n_low, total, s_min, s_max, what):
    frac = lambda n: f"{100 * n / max(total, 1):.1f} %"
    name = lambda n: what if n != 1 else what[:-1]
    return [f"> {_pct(s_max)} %: {n_high} {name(n_high)} ({frac(n_high)})",
            f"< {_pct(s_min)} %: {n_low} {name(n_low)} ({frac(n_low)})"]


def _invalid_legend(img, x, y, texts, fs):
    y = swatch(img, x, y, INVALID_HIGH, texts[0], fs)
    return swatch(img, x, y, INVALID_LOW, texts[1], fs)


def _split_by_validity(sigma, s_min, s_max):
    """Out of range by the report's own criterion, so picture and report agree."""
    high = sigma > s_max + SIGMA_TOL
    low = sigma < s_min - SIGMA_TOL
    return high, low, ~(high | low)


def _sigma_colors(sigma, s_min, s_max):
    high, low, _ = _split_by_validity(sigma, s_min, s_max)
    col = colormap(sigma, s_min, s_max, "shrink").astype(np.float64)
    col[high] = INVALID_HIGH
    col[low] = INVALID_LOW
    return col


def _face_sigma(n, faces, printing_edges, sigma):
    """Shrink per face for the background tint: the mean of its printing edges;
    faces without one (around fan centres) take the mean of their vertices' faces."""
    fe = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1).reshape(-1, 2)
    # A free layout's strokes end at points of their own, never at a face's corner.
    if len(printing_edges) and len(faces) and printing_edges.min() <= faces.max():
        idx = edge_index(printing_edges, fe).reshape(-1, 3)
    else:
        idx = np.full((len(faces), 3), -1)
    vals = np.where(idx >= 0, sigma[np.maximum(idx, 0)] if len(sigma) else 0.0, 0.0)
    # Sums over the three edges written out: along a 3-long axis numpy sums a row at a time.
    row_sum = lambda q: q[:, 0] + q[:, 1] + q[:, 2]
    cnt = row_sum((idx >= 0).astype(np.int64))
    with np.errstate(invalid="ignore", divide="ignore"):
        fs = row_sum(vals) / cnt
        has = cnt > 0
        num = np.bincount(faces[has].ravel(), np.repeat(fs[has], 3), minlength=n)
        den = np.bincount(faces[has].ravel(), minlength=n)
        vs = num / den
        around = vs[faces[~has]]
        ok = np.isfinite(around)
        fs[~has] = row_sum(np.where(ok, around, 0.0)) / row_sum(ok.astype(np.int64))
    return fs


def stress_image(xy, printing_edges, sigma, s_min, s_max, faces=None, px_per_mm=None, max_px=2000,
                 title="", line_px=None, face_sigma=None):
    """The flattened layout with printing edges coloured by shrink ratio (paper Fig. 1 right).

    Parameters
    ----------
    xy : (n, 2) float, mm
        Flat vertex positions (a third column is ignored).
    printing_edges : (p, 2) int
    sigma : (p,) float
        Shrink ratio per printing edge, ``1 - target_length / flat_length``.
    s_min, s_max : float
        The material's shrink range; edges outside are drawn magenta (> s_max)
        or black (< s_min) and counted in the legend.
    faces : (m, 3) int, optional
        When given, the sheet is filled with a pale tint of the local shrink and outlined.
    face_sigma : (m,) float, optional
        The shrink of each face for that tint; default: the mean of its printing edges
        (:func:`direction_image` passes a free layout's own).
    px_per_mm : float, optional
        Drawing scale; default gives ~1400 px on the longest side.
    max_px : int
        Cap on the drawing's longest side.
    title : str
    line_px : float, optional
        Stroke width; default from the mean isoline spacing.

    Returns
    -------
    PIL.Image (RGB) with ``info["px_per_mm"]`` and ``info["origin_px"]``.
    """
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    edges = np.asarray(printing_edges, dtype=np.int64).reshape(-1, 2)
    sigma = np.asarray(sigma, dtype=np.float64).reshape(-1)
    faces = None if faces is None else np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    lo, hi = extent(xy)
    size = hi - lo
    plan = _Plan(lo, hi, _scale(size.max(), px_per_mm, max_px), pad=12)
    p = plan.px(xy)
    total_len = float(edge_lengths(xy, edges).sum()) if len(edges) else 0.0
    area = float(face_areas(xy, faces).sum()) if faces is not None else 0.6 * float(size.prod())
    spacing_px = area / max(total_len, 1e-9) * plan.s
    lw = float(line_px) if line_px else float(np.clip(0.4 * spacing_px, 1.0, 3.5))

    if faces is not None and len(faces):
        if face_sigma is None:
            face_sigma = _face_sigma(len(xy), faces, edges, sigma)
        # Faces are a few px across, so a flat tint per face reads as a smooth field.
        tint = 0.28 * colormap(face_sigma, s_min, s_max, "shrink") + 0.72 * 246.0
        # Every pixel looked up at once, a white row last for those of no face (-1): the
        # sheet covers most of the canvas, so this beats scattering the covered ones.
        # float32: half the memory traffic of the drawing that follows.
        table = np.vstack([tint, np.full((1, 3), WHITE)]).astype(np.float32)
        if (tint == tint[0]).all():
            # One tint (one shrink everywhere, or none known): only whether a face
            # covers a pixel matters.
            fid = np.where(rasterize_triangles(p, np.zeros(len(p)), faces, (plan.h, plan.w),
                                               coverage=True), np.int32(0), np.int32(-1))
        else:
            fid = rasterize_triangles(p, np.zeros(len(p)), faces, (plan.h, plan.w))
        canvas = table.take(fid, axis=0)
        b = _boundary_edges(faces)
        draw_segments(canvas, p[b[:, 0]], p[b[:, 1]], (95, 95, 100), max(1.0, 0.6 * lw))
    else:
        canvas = np.full((plan.h, plan.w, 3), WHITE, np.float32)  # float32: half the memory traffic
    high, low, ok = _split_by_validity(sigma, s_min, s_max)
    col = _sigma_colors(sigma, s_min, s_max)
    draw_segments(canvas, p[edges[ok, 0]], p[edges[ok, 1]], col[ok], lw)
    bad = ~ok
    draw_segments(canvas, p[edges[bad, 0]], p[edges[bad, 1]], col[bad], max(1.6 * lw, 2.0))

    n = len(sigma)
    good = sigma[np.isfinite(sigma)]
    sub = (f"flat layout {size[0]:.1f} x {size[1]:.1f} mm  |  {n} printing edges  |  "
           f"invalid {100 * (high.sum() + low.sum()) / max(n, 1):.1f} %")
    texts = _invalid_texts(int(high.sum()), int(low.sum()), n, s_min, s_max, "edges")
    fig, bxy, (lx, ly), (fx, fy), fs = framed(to_image(canvas), title or "shrink ratio", sub,
                                              legend_texts=texts)
    _, yb = colorbar(fig, lx, ly, 26, min(360, max(200, plan.h // 2)), "shrink", s_min, s_max,
                     "shrink (%)", scale=100, fs=fs)
    y = _invalid_legend(fig, lx, yb + fs, texts, fs)
    if len(good):
        q = np.percentile(good, [5, 95])
        stat_lines(fig, lx, y + fs // 2, [f"mean {_pct(good.mean())} %",
                                           f"p05-p95 {_pct(q[0])}-{_pct(q[1])} %",
                                           f"min {_pct(good.min())}, max {_pct(good.max())} %"], fs)
    scale_bar(fig, bxy[0] + 12, fy + fs, plan.s, min(0.3 * plan.w, 600), fs)
    return plan.tag(fig, bxy)


def direction_image(xy, faces, direction, sigma, s_min, s_max, **kw):
    """:func:`stress_image` of a free-direction layout: a stroke along each triangle's
    print direction, coloured by its shrink ``sigma`` ((m,)), on the sheet tinted by the
    same (the strokes share no edge with the triangles, so the tint cannot be had from
    them). ``kw``: :func:`stress_image`'s drawing options."""
    pts, ticks, sig = direction_ticks(xy, faces, direction, sigma)
    return stress_image(pts, ticks, sig, s_min, s_max, faces=faces, face_sigma=sig, **kw)


def direction_ticks(xy, faces, direction, sigma, length_fraction=0.7):
    """Short strokes along each triangle's print direction, through its centroid, for
    :func:`stress_image` of a free-direction layout.

    Returns (points (n + 2m, 2) mm: ``xy`` then the strokes' ends, edges (m, 2) int,
    sigma (m,)): the strokes as "printing edges" coloured by their triangle's shrink
    (drawn by :func:`direction_image`).
    """
    xy = np.asarray(xy, dtype=float)[:, :2]
    P = xy[faces]
    c = (P[:, 0] + P[:, 1] + P[:, 2]) / 3  # the mean, summed as np.mean does, not a row at a time
    size = np.sqrt(face_areas(xy, faces))
    half = (0.5 * length_fraction * size)[:, None] * np.asarray(direction, dtype=float)
    n, m = len(xy), len(faces)
    pts = np.concatenate([xy, c - half, c + half])
    edges = np.stack([n + np.arange(m), n + m + np.arange(m)], axis=1)
    return pts, edges, np.asarray(sigma, dtype=float)


def _as_segments(paths):
    """Polylines (list of (k, 2)) or an (t, 2, 2) array -> (p0, p1) each (s, 2)."""
    if paths is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    if isinstance(paths, np.ndarray) and paths.ndim == 3:
        return paths[:, 0, :2].astype(float), paths[:, -1, :2].astype(float)
    p0 = [np.asarray(q, float)[:-1, :2] for q in paths if len(q) > 1]
    p1 = [np.asarray(q, float)[1:, :2] for q in paths if len(q) > 1]
    if not p0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.concatenate(p0), np.concatenate(p1)


def toolpath_image(traces, sigma, s_min, s_max, path_width_mm, travel=None, px_per_mm=None,
                   max_px=2000, title="", dry=None):
    """Tool paths coloured by shrink ratio, travel moves dashed, dry moves dotted, trace
    starts marked.

    Parameters
    ----------
    traces : list of (k_i, 2) float, mm
        Ordered printing paths of one layer.
    sigma : list of (k_i - 1,) float
        Shrink ratio per segment.
    s_min, s_max : float
        Valid shrink range; segments outside are magenta / black.
    path_width_mm : float
        Paths are drawn at 70 % of this width so neighbours stay distinguishable.
    travel : list of (k, 2) float or (t, 2, 2) float, mm, optional
        Non-printing moves (from, to).
    dry : list of (k_i - 1,) bool, optional
        Segments of the traces moved without extruding (hops over printed paths).
    px_per_mm, max_px, title : as in :func:`stress_image`.

    Returns
    -------
    PIL.Image with ``info["px_per_mm"]`` and ``info["origin_px"]``.
    """
    traces = [np.asarray(t, dtype=np.float64)[:, :2] for t in traces]
    p0, p1 = _as_segments(traces)
    sig = np.concatenate([np.asarray(s, float).reshape(-1) for s in sigma]) if len(sigma) else np.zeros(0)
    wet = (~np.concatenate([np.asarray(d, bool).reshape(-1) for d in dry]) if dry and len(sig)
           else np.ones(len(sig), bool))
    d0, d1 = p0[~wet], p1[~wet]
    p0, p1, sig = p0[wet], p1[wet], sig[wet]
    t0, t1 = _as_segments(travel)
    pts = np.concatenate([p0, p1, t0, t1]) if len(p0) + len(t0) else np.zeros((1, 2))
    lo, hi = extent(pts)
    size = hi - lo
    plan = _Plan(lo, hi, _scale(size.max(), px_per_mm, max_px), pad=16)
    canvas = np.full((plan.h, plan.w, 3), WHITE, np.float32)  # float32: half the memory traffic
    lw = 0.7 * path_width_mm * plan.s
    high, low, ok = _split_by_validity(sig, s_min, s_max)
    col = _sigma_colors(sig, s_min, s_max)
    prio = np.where(ok, 0, 1)
    draw_segments(canvas, plan.px(p0), plan.px(p1), col, lw, priority=prio)
    if len(t0):
        q0, q1, _ = dash_segments(plan.px(t0), plan.px(t1), 6.0, 4.0)
        draw_segments(canvas, q0, q1, TRAVEL_COLOR, 1.2)
    if len(d0):
        q0, q1, _ = dash_segments(plan.px(d0), plan.px(d1), 2.0, 2.0)
        draw_segments(canvas, q0, q1, DRY_COLOR, max(1.5, 0.3 * lw))
    starts = np.array([t[0] for t in traces if len(t)]).reshape(-1, 2)
    d = max(11.0, 2.5 * lw) if len(traces) <= 40 else max(7.0, 1.5 * lw)  # many: keep them small
    sp = plan.px(starts)
    draw_segments(canvas, sp, sp, INK, d + 3)
    draw_segments(canvas, sp, sp, START_COLOR, d)
    body = to_image(canvas)
    if 0 < len(traces) <= 40:  # numbered in printing order while the numbers stay legible
        draw = ImageDraw.Draw(body)
        for k, q in enumerate(sp):
            draw.text((q[0] + 0.6 * d, q[1] - 0.6 * d - 14), str(k + 1), font=font(16), fill=INK,
                      stroke_width=2, stroke_fill=(255, 255, 255))

    n = len(sig)
    step = p1 - p0  # lengths written out: np.linalg.norm on (s, 2) rows loops a row at a time
    length_mm = float(np.sqrt(step[:, 0] * step[:, 0] + step[:, 1] * step[:, 1]).sum())
    sub = (f"{counted(len(traces), 'trace')}  |  {n} segments  |  {length_mm / 1000:.2f} m of path per layer  |  "
           f"{len(t0)} travel moves")
    texts = _invalid_texts(int(high.sum()), int(low.sum()), n, s_min, s_max, "segments")
    fig, bxy, (lx, ly), (fx, fy), fs = framed(body, title or "tool paths", sub, legend_texts=texts)
    _, yb = colorbar(fig, lx, ly, 26, min(360, max(200, plan.h // 2)), "shrink", s_min, s_max,
                     "shrink (%)", scale=100, fs=fs)
    y = _invalid_legend(fig, lx, yb + fs, texts, fs)
    y = swatch(fig, lx, y, START_COLOR, "trace start (numbered)", fs, shape="dot")
    y = swatch(fig, lx, y, TRAVEL_COLOR, "travel move", fs, shape="dash")
    if len(d0):
        y = swatch(fig, lx, y, DRY_COLOR, "dry move (over printed paths)", fs, shape="dash")
    stat_lines(fig, lx, y + fs // 2, [f"path width {fmt_number(path_width_mm, 0.01)} mm",
                                       "(drawn at 70 %)"], fs)
    scale_bar(fig, bxy[0] + 16, fy + fs, plan.s, min(0.3 * plan.w, 600), fs)
    return plan.tag(fig, bxy)


def preview_image(target_vertices, faces, simulated_vertices, displacement_mm, title="",
                  panel_px=(None, None), elevation_deg=35.0, azimuth_deg=-30.0, vmax_mm=None,
                  contour_mm="auto", inverted_faces=None, given_vertices=None,
                  target_label="target"):
    """Target and simulated shape side by side in one oblique view, error as colour; with
    ``given_vertices``, the file as given, the sheet, and the planned target third.

    Parameters
    ----------
    target_vertices : (n, 3) float, mm
    faces : (m, 3) int
    simulated_vertices : (n, 3) float, mm
        Forward-simulation result, rigidly aligned to the target.
    displacement_mm : (n,) float
        Distance of each simulated vertex from its target, mm.
    title : str
    panel_px : (width, height) of each view; width None: ``PREVIEW_PX_PER_MM`` across the
        target within ``PREVIEW_PANEL_PX``; height None fits the shape.
    elevation_deg, azimuth_deg : view direction (35 degrees above the horizon by default).
    vmax_mm : float, optional
        Top of the colour scale; default a round number above the maximum.
    contour_mm : float, "auto" or None
        Faint height contours on both shapes ("auto": about ten over the height).
    inverted_faces : (m,) bool, optional
        Faces of the regions that settled the other way up
        (:func:`pipeline.simulation.inverted.inverted_regions`), hatched on the simulated shape.
    given_vertices : (n, 3) float, mm, optional
        The input as given at each target vertex (before smoothing or lowering): drawn
        first, the sheet beside it (``simulated_vertices`` and ``displacement_mm`` then
        against it), the target planned third under ``target_label``.

    Returns
    -------
    PIL.Image (RGB).
    """
    tv = np.asarray(target_vertices, np.float64)
    sv = np.asarray(simulated_vertices, np.float64)
    disp = np.asarray(displacement_mm, np.float64).reshape(-1)
    faces = np.asarray(faces, np.int64)
    fin = disp[np.isfinite(disp)]
    mean_d = float(fin.mean()) if len(fin) else float("nan")
    max_d = float(fin.max()) if len(fin) else float("nan")
    vmax = float(vmax_mm) if vmax_mm else nice_ceil(max(max_d if np.isfinite(max_d) else 0, 0.1))
    height_mm = float(np.ptp(tv[:, 2])) if len(tv) else 0.0
    if contour_mm == "auto":
        contour_mm = nice_ceil(height_mm / 10) if height_mm > 0 else None
    gv = None if given_vertices is None else np.asarray(given_vertices, np.float64)
    shown = [tv, sv] if gv is None else [gv, sv, tv]
    lo, hi = extent(tv[:, :2]) if len(tv) else (np.zeros(2), np.zeros(2))
    diam = hi - lo
    pw, ph = panel_px
    if pw is None:
        pw = int(np.clip(PREVIEW_PX_PER_MM * float(diam.max()), *PREVIEW_PANEL_PX))
    if ph is None:  # fit the width, then take the height the shape needs (within reason)
        (_, _), s = view_fit(shown, (pw, 10 * pw), elevation_deg, azimuth_deg)
        cam = camera_basis(elevation_deg, azimuth_deg)
        sy = np.concatenate([project(v, cam[1:2]) for v in shown])
        ph = int(np.clip(np.ptp(sy) * s / 0.84 + 1, 0.45 * pw, 1.1 * pw))
    fit = view_fit(shown, (pw, ph), elevation_deg, azimuth_deg)
    kw = dict(size_px=(pw, ph), elevation_deg=elevation_deg, azimuth_deg=azimuth_deg, fit=fit,
              contour_mm=contour_mm)
    hatch = None if inverted_faces is None or not np.any(inverted_faces) else inverted_faces
    b, _ = shaded_view(sv, faces, disp, 0.0, vmax, "displacement", hatch=hatch, **kw)
    sim_label = f"simulated (mean {mean_d:.2f} mm, max {max_d:.2f} mm)"
    if gv is None:
        panels = [(shaded_view(tv, faces, None, **kw)[0], "target"), (b, sim_label)]
    else:
        panels = [(shaded_view(gv, faces, None, **kw)[0], "your file, as given"),
                  (b, sim_label.replace("simulated (", "simulated (from your file: ")),
                  (shaded_view(tv, faces, None, **kw)[0], target_label)]
    fs = 16
    label_h = 34
    body = Image.new("RGB", (len(panels) * pw, ph + label_h), (255, 255, 255))
    draw = ImageDraw.Draw(body)
    for k, (im, label) in enumerate(panels):
        body.paste(im, (k * pw, label_h), im)
        tw = text_size(label, font(fs))[0]
        draw.text((k * pw + (pw - tw) / 2, 6), label, font=font(fs), fill=INK)
    for k in range(1, len(panels)):
        draw.line([k * pw, label_h, k * pw, ph + label_h - 10], fill=(225, 225, 228), width=1)
    sub = (f"target {diam[0]:.0f} x {diam[1]:.0f} x {height_mm:.1f} mm  |  {len(faces)} triangles  |  "
           f"view from {elevation_deg:.0f} deg above the horizon")
    if contour_mm:
        sub += f"  |  contours every {fmt_number(contour_mm)} mm"
    fig, bxy, (lx, ly), (fx, fy), fs = framed(body, title or "preview", sub, legend_w=120,
                                              legend_min_h=260, footer_h=50, fs=fs,
                                              legend_texts=["displacement (mm)"])
    bar_h = int(np.clip(ph - 90, 150, 320))
    colorbar(fig, lx, ly + label_h, 24, bar_h, "displacement", 0.0, vmax,
             "displacement (mm)", fs=fs)
    if hatch is not None:
        swatch(fig, lx, ly + label_h + bar_h + 2 * fs, INVERTED, "inverted", fs)
    x = scale_bar(fig, bxy[0] + 20, fy + 12, fit[1], 0.35 * pw, fs)
    ImageDraw.Draw(fig).text((x + 8, fy + 6), "(across the view)", font=font(fs - 3), fill=MUTED)
    return fig


def montage(images, labels, height_px=420, pad_px=18, title="", columns=None):
    """Images in a grid at one height per row, each with a numbered label above (README figure).

    Parameters
    ----------
    images : list of PIL.Image
    labels : list of str (same length)
    height_px : int
        Every image is scaled to this height.
    title : str, optional
    columns : int, optional
        Images per row (default: all in one row).

    Returns
    -------
    PIL.Image (RGB).
    """
    ims = [im.convert("RGB") for im in images]
    ims = [im.resize((max(1, round(im.width * height_px / im.height)), height_px), Image.LANCZOS)
           for im in ims]
    cols = max(1, int(columns or len(ims)))
    rows = [ims[k:k + cols] for k in range(0, len(ims), cols)]
    fs = 18
    label_h = int(fs * 1.8)
    title_h = int(fs * 2.4) if title else 0
    cell_h = label_h + height_px + pad_px
    w = max(pad_px + sum(im.width + pad_px for im in row) for row in rows)
    out = Image.new("RGB", (w, title_h + cell_h * len(rows)), (255, 255, 255))
    draw = ImageDraw.Draw(out)
    if title:
        draw.text((pad_px, pad_px // 2), title, font=font(int(fs * 1.25)), fill=INK)
    for k, (im, label) in enumerate(zip(ims, labels)):
        r, c = divmod(k, cols)
        x = pad_px + sum(q.width + pad_px for q in rows[r][:c])
        y = title_h + r * cell_h
        draw.text((x, y + 4), f"{k + 1}. {label}" if len(ims) > 1 else label, font=font(fs), fill=INK)
        out.paste(im, (x, y + label_h))
    return out
