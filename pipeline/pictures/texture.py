"""Screen-print texture of the flat sheet (paper section 6.5).

The sheet is printed flat and shrinks afterwards, so a texture drawn on the flat
layout is squeezed with it: a face whose area drops from ``a_flat`` to
``a_target`` packs its ink dots ``a_flat / a_target`` times denser and looks
darker (paper Fig. 10). Printing each face with opacity ``a_target / a_flat``
cancels that, so after the hot-water bath the ink density per unit of target
surface is what the colour image asked for. Faces that would have to grow
(``a_target > a_flat``) cannot be lightened past full ink and are clipped to 1.

Frames (all mm):

- *layout*: the flat sheet's own coordinates ``xy`` (as the flattening returns them);
- *bbox*: the layout shifted so the lower-left corner of its bounding box is 0, 0.
  The G-code places the part by its bounding box (``pipeline.gcode.writer`` centres it on
  the bed), so bbox coordinates plus the bed position of that corner give bed
  coordinates;
- *image*: the PNG and the SVG share one page: the bbox grown by ``margin_mm`` on
  every side, +y up in mm, rows downward in pixels (pixel (row i, col j) covers
  ``[j, j+1) x [i, i+1)`` in pixel units, as in :mod:`pipeline.pictures.raster`).

Registration marks (crosshair circles) sit at the four corners of the bbox,
pushed ``margin_mm / 2`` outwards along x and y, so they never touch the part and
stay inside the page.
"""

import html

import numpy as np
from PIL import Image
from scipy.ndimage import map_coordinates

from pipeline.errors import PlanError
from pipeline.geometry import boundary_loops, face_areas
from pipeline.pictures.raster import draw_segments, pixel_barycentrics, rasterize_triangles

__all__ = ["MM_PER_INCH", "MARK_NAMES", "vertex_colors", "face_opacity", "registration_marks",
           "texture_image", "save_texture", "boundary_loops", "outline_svg"]

MM_PER_INCH = 25.4
MARK_NAMES = ("lower_left", "lower_right", "upper_right", "upper_left")
# Mark geometry as fractions of the margin: centre margin/2 outside the bbox,
# so circle (0.3) and cross arms (0.45) end 0.05 * margin inside the page edge.
_MARK_OFFSET = 0.5
_MARK_RADIUS = 0.3
_MARK_ARM = 0.45
_MARK_LINE_MM = 0.2
# A screen larger than this many pixels a side is a unit mistake, not a part.
_MAX_SIDE_PX = 30000
# Pixels per barycentric chunk: bounds pixel_barycentrics' (k, 9) temporaries.
_BAND_PX = 1 << 20


def _bad(message, fix=None, **details):
    return PlanError(message, code="texture.bad_input", fix=fix, details=details)


def _check_inputs(vertices, faces, xy, colors):
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    xy = np.asarray(xy, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise _bad("target vertices must be (n, 3), got %s" % (vertices.shape,))
    n = len(vertices)
    if xy.shape != (n, 2):
        raise _bad("flat layout must be (%d, 2) like the target vertices, got %s" % (n, xy.shape),
                   fix="pass the flattened positions of the same vertices, in the same order")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise _bad("faces must be a non-empty (m, 3) array, got %s" % (faces.shape,))
    if faces.min() < 0 or faces.max() >= n:
        raise _bad("faces index vertices outside 0..%d" % (n - 1))
    if not (np.all(np.isfinite(vertices)) and np.all(np.isfinite(xy))):
        raise _bad("vertex positions contain NaN or infinity")
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (n, 3):
            raise _bad("colours must be (%d, 3) RGB per vertex, got %s" % (n, colors.shape))
    return vertices, faces, xy, colors


def vertex_colors(hf, vertices):
    """Colour of the height field's image at each vertex, bilinear.

    Parameters
    ----------
    hf : pipeline.geometry.HeightField
        With ``color`` (rows, cols, 3) uint8; row 0 north, x = col * pixel_mm,
        y = (rows - 1 - row) * pixel_mm.
    vertices : (n, 2) or (n, 3) float, mm
        Positions in the height field's plane (z ignored).

    Returns
    -------
    colors : (n, 3) uint8
    """
    if hf.color is None:
        raise PlanError("the height field has no colour image", code="texture.no_color",
                        file=hf.source or None,
                        fix="add NAME.color.png beside the input, or skip the texture")
    color = np.asarray(hf.color)
    rows, cols = hf.rc(np.asarray(vertices, dtype=np.float64)[:, :2])
    # Outermost vertices can sit a hair past the last sample: hold the edge colour.
    coords = np.stack([rows, cols])
    out = np.stack([map_coordinates(color[..., c].astype(np.float64), coords, order=1,
                                    mode="nearest") for c in range(3)], axis=1)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def face_opacity(vertices, faces, xy):
    """Ink opacity per face: target area over flat area, clipped to [0, 1].

    Parameters
    ----------
    vertices : (n, 3) float, mm (target surface)
    faces : (m, 3) int
    xy : (n, 2) float, mm (flat layout, same vertex order)

    Returns
    -------
    opacity : (m,) float in [0, 1]
        0 for faces with no flat area (they print no pixels anyway).
    a_target, a_flat : (m,) float, mm^2
    """
    a_t = face_areas(np.asarray(vertices, dtype=np.float64), faces)
    a_f = face_areas(np.asarray(xy, dtype=np.float64), faces)
    ratio = np.divide(a_t, a_f, out=np.zeros_like(a_t), where=a_f > 1e-12)
    return np.clip(ratio, 0.0, 1.0), a_t, a_f


def registration_marks(xy, margin_mm=10.0):
    """Centres of the four registration marks in the layout frame.

    Parameters
    ----------
    xy : (n, 2) float, mm (flat layout)
    margin_mm : float
        Page margin around the layout's bounding box; marks sit ``margin_mm / 2``
        outside each corner along x and y.

    Returns
    -------
    marks : (4, 2) float, mm, in the order of :data:`MARK_NAMES`
        (lower-left, lower-right, upper-right, upper-left).
    """
    xy = np.asarray(xy, dtype=np.float64)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    d = _MARK_OFFSET * float(margin_mm)
    return np.array([[lo[0] - d, lo[1] - d], [hi[0] + d, lo[1] - d],
                     [hi[0] + d, hi[1] + d], [lo[0] - d, hi[1] + d]])


def _page(xy, margin_mm, px_mm):
    """Page frame: (top-left corner in layout mm, size in px, size in mm)."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    ext = hi - lo + 2 * margin_mm
    # Round up so the page holds the whole layout; the < 1 px excess goes right/bottom.
    size_px = np.ceil(ext / px_mm - 1e-6).astype(np.int64)
    corner = np.array([lo[0] - margin_mm, hi[1] + margin_mm])
    return corner, size_px, ext


def _to_px(p, corner, px_mm):
    """Layout mm (..., 2) to continuous pixel coordinates (x = column, y = row)."""
    p = np.asarray(p, dtype=np.float64)
    return np.stack([(p[..., 0] - corner[0]) / px_mm, (corner[1] - p[..., 1]) / px_mm], axis=-1)


def _mark_segments(center_mm, margin_mm, n_arc=96):
    """Circle (as a polygon) plus crosshair of one mark: (p0, p1) each (s, 2) mm."""
    r, arm = _MARK_RADIUS * margin_mm, _MARK_ARM * margin_mm
    t = np.linspace(0.0, 2 * np.pi, n_arc + 1)
    ring = center_mm + r * np.stack([np.cos(t), np.sin(t)], axis=1)
    cross0 = center_mm + np.array([[-arm, 0.0], [0.0, -arm]])
    cross1 = center_mm + np.array([[arm, 0.0], [0.0, arm]])
    return np.vstack([ring[:-1], cross0]), np.vstack([ring[1:], cross1])


def _composite_marks(rgba, centers_mm, corner, px_mm, margin_mm):
    """Draw opaque black marks over ``rgba`` ((h, w, 4) uint8) in place.

    Each mark is drawn on its own small patch (not a page-sized float canvas:
    at 300 dpi that alone would be ~100 MB) and laid over with straight-alpha
    "over" compositing.
    """
    h, w = rgba.shape[:2]
    width_px = max(_MARK_LINE_MM / px_mm, 1.5)
    reach = (_MARK_ARM * margin_mm) / px_mm + width_px + 2
    for c in centers_mm:
        cp = _to_px(c, corner, px_mm)
        x0, y0 = max(int(np.floor(cp[0] - reach)), 0), max(int(np.floor(cp[1] - reach)), 0)
        x1, y1 = min(int(np.ceil(cp[0] + reach)), w), min(int(np.ceil(cp[1] + reach)), h)
        if x1 <= x0 or y1 <= y0:
            continue
        p0, p1 = _mark_segments(np.asarray(c), margin_mm)
        shift = np.array([x0, y0], dtype=np.float64)
        cov = np.zeros((y1 - y0, x1 - x0, 3))
        draw_segments(cov, _to_px(p0, corner, px_mm) - shift, _to_px(p1, corner, px_mm) - shift,
                      (255.0, 255.0, 255.0), width_px=width_px)
        k = cov[..., 0] / 255.0
        patch = rgba[y0:y1, x0:x1].astype(np.float64)
        a = patch[..., 3] / 255.0
        out_a = k + a * (1 - k)
        # Ink is black: only the old colour's weighted share survives.
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(out_a > 0, a * (1 - k) / out_a, 0.0)
        patch[..., :3] *= scale[..., None]
        patch[..., 3] = 255.0 * out_a
        rgba[y0:y1, x0:x1] = np.clip(np.rint(patch), 0, 255).astype(np.uint8)


def texture_image(vertices, faces, xy, colors, dpi=300, margin_mm=10.0, marks=True):
    """The screen-print texture of the flat layout at 1:1 print scale.

    Parameters
    ----------
    vertices : (n, 3) float, mm
        Target surface (faces counter-clockwise from +z).
    faces : (m, 3) int
    xy : (n, 2) float, mm
        Flat layout of the same vertices, the sheet as printed.
    colors : (n, 3) uint8 (or float 0-255)
        Colour of each vertex on the target surface (see :func:`vertex_colors`).
    dpi : float
        Pixels per inch; one pixel is ``25.4 / dpi`` mm on paper and screen.
    margin_mm : float
        Transparent margin around the layout's bounding box (holds the marks).
    marks : bool
        Draw the four registration marks.

    Returns
    -------
    image : PIL.Image, mode RGBA
        Straight (not premultiplied) alpha: RGB is the barycentric colour, alpha
        the face's opacity ``a_target / a_flat``; transparent outside the part.
        ``image.info["dpi"]`` is set, but PIL only writes it to the file when
        saved with ``image.save(path, dpi=(dpi, dpi))``: use :func:`save_texture`.
    info : dict
        ``dpi``; ``px_per_mm``; ``size_px`` [w, h]; ``size_mm`` [w, h] (of the
        pixel grid); ``margin_mm``; ``layout_bbox_mm`` [x0, y0, x1, y1] (layout
        frame); ``origin_px`` [x, y] (continuous pixel position of the bbox's
        lower-left corner); ``opacity`` {min, mean, max} (mean weighted by flat
        area: the sheet's overall ink density), ``clipped_faces`` (faces whose
        target area exceeds the flat one); ``marks``: list of {name, bbox_mm,
        layout_mm, px, radius_mm} with ``px`` the continuous pixel position
        [x = column, y = row] of the mark's centre.
    """
    vertices, faces, xy, colors = _check_inputs(vertices, faces, xy, colors)
    dpi = float(dpi)
    margin_mm = float(margin_mm)
    if not dpi > 0 or not margin_mm >= 0:
        raise _bad("dpi must be positive and margin_mm non-negative (got %g, %g)" % (dpi, margin_mm))
    px_mm = MM_PER_INCH / dpi
    corner, size_px, _ = _page(xy, margin_mm, px_mm)
    w, h = int(size_px[0]), int(size_px[1])
    if max(w, h) > _MAX_SIDE_PX:
        raise PlanError("texture would be %d x %d pixels" % (w, h), code="texture.too_large",
                        fix="check the layout is in mm and the dpi is sensible (300 is typical)",
                        details={"size_px": [w, h], "dpi": dpi})

    opacity, a_t, a_f = face_opacity(vertices, faces, xy)
    p = _to_px(xy, corner, px_mm)
    # The layout is planar: any constant depth works, ties go to the lower face id.
    face_id = rasterize_triangles(p, np.zeros(len(p)), faces, (h, w))
    rgba = np.zeros((h, w, 4), np.uint8)
    cols_f = np.asarray(colors, dtype=np.float64)
    alpha_f = np.rint(255.0 * opacity)
    band = max(1, _BAND_PX // max(w, 1))
    for r0 in range(0, h, band):
        sub = face_id[r0:r0 + band]
        rows, cols, face, wts = pixel_barycentrics(p - [0.0, r0], faces, sub)
        rgb = np.einsum("kj,kjc->kc", wts, cols_f[faces[face]])
        out = rgba[r0:r0 + band]
        out[rows, cols, :3] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
        out[rows, cols, 3] = alpha_f[face].astype(np.uint8)

    lo, hi = xy.min(axis=0), xy.max(axis=0)
    centers = registration_marks(xy, margin_mm)
    if marks:
        _composite_marks(rgba, centers, corner, px_mm, margin_mm)
    mark_px = _to_px(centers, corner, px_mm)
    live = a_f > 1e-12
    info = {
        "dpi": dpi,
        "px_per_mm": 1.0 / px_mm,
        "size_px": [w, h],
        "size_mm": [w * px_mm, h * px_mm],
        "margin_mm": margin_mm,
        "layout_bbox_mm": [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])],
        "origin_px": [float(v) for v in _to_px(lo, corner, px_mm)],
        "opacity": {
            "min": float(opacity[live].min()) if live.any() else 0.0,
            "mean": float(np.sum(opacity * a_f) / max(np.sum(a_f), 1e-12)),
            "max": float(opacity[live].max()) if live.any() else 0.0,
        },
        "clipped_faces": int(np.count_nonzero(a_t > a_f * (1 + 1e-9))),
        "marks": [{"name": name, "bbox_mm": [float(v) for v in c - lo],
                   "layout_mm": [float(v) for v in c], "px": [float(v) for v in q],
                   "radius_mm": _MARK_RADIUS * margin_mm}
                  for name, c, q in zip(MARK_NAMES, centers, mark_px)] if marks else [],
    }
    image = Image.fromarray(rgba)
    image.info["dpi"] = (dpi, dpi)
    return image, info


def save_texture(image, out, dpi=None):
    """Write ``image`` as PNG with its resolution in the file (pHYs chunk).

    out : path or binary file object; dpi : float, default ``image.info["dpi"]``.
    Without the pHYs chunk screen-making software assumes 72 or 96 dpi and the
    print comes out at the wrong size.
    """
    dpi = float(dpi if dpi is not None else image.info["dpi"][0])
    image.save(out, format="PNG", dpi=(dpi, dpi))


def _fmt(v):
    s = "%.3f" % v
    s = s.rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def outline_svg(xy, faces, marks=True, margin_mm=10.0, dpi=None):
    """SVG of the flat part's outline and registration marks, 1:1 in mm.

    The page is the one of :func:`texture_image` (bbox plus ``margin_mm``, y
    flipped so +y is up as in the PNG), so the two overlay when printed at
    100 %. Give ``dpi`` to round the page up to the PNG's pixel grid exactly.

    Parameters
    ----------
    xy : (n, 2) float, mm (flat layout)
    faces : (m, 3) int
    marks : bool, (k, 2) float mm in the layout frame, or the ``info["marks"]``
        list from :func:`texture_image` (its ``layout_mm`` are used).
    margin_mm : float
    dpi : float, optional

    Returns
    -------
    svg : str
        An SVG document: ``width``/``height`` in mm, ``viewBox`` in mm; the
        outline is ``<path id="outline">`` (one subpath per boundary loop,
        even-odd), each mark a ``<g class="mark">`` with a circle and a cross.
    """
    xy = np.asarray(xy, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise _bad("flat layout must be a finite (n, 2) array")
    margin_mm = float(margin_mm)
    px_mm = MM_PER_INCH / float(dpi) if dpi else None
    if px_mm:
        corner, size_px, _ = _page(xy, margin_mm, px_mm)
        size = size_px * px_mm
    else:
        corner, _, size = _page(xy, margin_mm, 1.0)

    def page(pts):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        return np.stack([pts[:, 0] - corner[0], corner[1] - pts[:, 1]], axis=1)

    subpaths = []
    for loop in boundary_loops(faces):
        q = page(xy[loop])
        pts = " L".join("%s %s" % (_fmt(a), _fmt(b)) for a, b in q)
        subpaths.append("M" + pts + " Z")

    if marks is True:
        centers = registration_marks(xy, margin_mm)
    elif marks is False or marks is None:
        centers = np.zeros((0, 2))
    elif len(marks) and isinstance(marks[0], dict):
        centers = np.array([m["layout_mm"] for m in marks], dtype=np.float64)
    else:
        centers = np.asarray(marks, dtype=np.float64).reshape(-1, 2)

    r, arm = _MARK_RADIUS * margin_mm, _MARK_ARM * margin_mm
    mark_svg = []
    for name, c in zip(list(MARK_NAMES) + ["mark%d" % i for i in range(4, len(centers))],
                       page(centers)):
        x, y = c
        mark_svg.append(
            '  <g class="mark" id=%s>\n'
            '    <circle cx="%s" cy="%s" r="%s"/>\n'
            '    <path d="M%s %s H%s M%s %s V%s"/>\n'
            '  </g>' % (_attr(name), _fmt(x), _fmt(y), _fmt(r),
                        _fmt(x - arm), _fmt(y), _fmt(x + arm), _fmt(x), _fmt(y - arm),
                        _fmt(y + arm)))

    w, h = (float(v) for v in size)
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<svg xmlns="http://www.w3.org/2000/svg" version="1.1" width="%smm" height="%smm" '
        'viewBox="0 0 %s %s">' % (_fmt(w), _fmt(h), _fmt(w), _fmt(h)),
        '  <title>flat sheet outline and registration marks, 1:1, mm</title>',
        '  <path id="outline" fill="none" fill-rule="evenodd" stroke="#000000" '
        'stroke-width="%s" d="%s"/>' % (_fmt(_MARK_LINE_MM), " ".join(subpaths)),
        '  <g id="marks" fill="none" stroke="#000000" stroke-width="%s">' % _fmt(_MARK_LINE_MM),
        *mark_svg,
        '  </g>',
        '</svg>',
        '',
    ]
    return "\n".join(lines)


def _attr(text):
    """``text`` as a quoted XML attribute value (xml.sax.saxutils.quoteattr would do, but
    imports urllib.request and with it http.client and email: 35 ms of every plan's
    start)."""
    return '"%s"' % html.escape(text, quote=True)
