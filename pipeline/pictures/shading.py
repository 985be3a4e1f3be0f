"""Shaded 3-D views of triangle meshes (numpy + Pillow): orthographic camera, z-buffer,
Lambert + Blinn-Phong light per vertex interpolated per pixel, anti-aliased silhouettes,
soft ground shadow, height contours.

Used by :func:`pipeline.pictures.render.preview_image`; usable on its own for thumbnails.
"""

import numpy as np
from PIL import Image, ImageFilter

from pipeline.pictures.figure import INVERTED, colormap, extent
from pipeline.pictures.raster import edge_functions, face_planes, rasterize_triangles


def _vertex_normals(vertices, faces):
    """Area-weighted unit vertex normals: their x, y and z, each (n,).

    Written out on contiguous coordinate rows (what ``np.cross`` and ``np.linalg.norm``
    compute, in the same order): on (m, 3) arrays they loop per face."""
    vt = np.ascontiguousarray(vertices.T)
    (x0, x1, x2), (y0, y1, y2), (z0, z1, z2) = (q[faces.T] for q in vt)
    ax, ay, az, bx, by, bz = x1 - x0, y1 - y0, z1 - z0, x2 - x0, y2 - y0, z2 - z0
    corner = faces.ravel()
    n = [np.bincount(corner, np.repeat(f, 3), minlength=len(vertices))
         for f in (ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx)]
    norm = np.maximum(np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), 1e-12)
    return [q / norm for q in n]


def project(p, rows):
    """``p @ rows.T`` for (k, 3) by (j, 3), written out: BLAS threads make tall
    thin products slow on small shared machines."""
    r = np.asarray(rows, dtype=p.dtype)
    return np.stack([p[:, 0] * r[j, 0] + p[:, 1] * r[j, 1] + p[:, 2] * r[j, 2]
                     for j in range(len(r))], axis=1)


def camera_basis(elevation_deg, azimuth_deg):
    """Orthographic camera basis (right, up, view) as rows of a (3, 3) matrix.

    Azimuth 0 looks north from the south; positive azimuth swings the camera
    counter-clockwise seen from above. ``view`` points into the scene.
    """
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    right = np.array([np.cos(az), np.sin(az), 0.0])
    fwd = np.array([-np.sin(az), np.cos(az), 0.0])
    up = np.sin(el) * fwd + np.cos(el) * np.array([0.0, 0.0, 1.0])
    view = np.cos(el) * fwd - np.sin(el) * np.array([0.0, 0.0, 1.0])
    return np.stack([right, up, view])


def _light(cam):
    """Key light from the upper left, slightly behind the viewer (world coordinates)."""
    l = -0.5 * cam[0] + 0.55 * cam[1] - 0.45 * cam[2] + np.array([0.0, 0.0, 0.5])
    return l / np.linalg.norm(l)


def shaded_view(vertices, faces, values=None, vmin=0.0, vmax=1.0, cmap="displacement",
                base_color=(178, 188, 204), size_px=(800, 600), elevation_deg=35.0,
                azimuth_deg=-30.0, fit=None, supersample=2, shadow=True, contour_mm=None,
                hatch=None):
    """Shaded orthographic render of a triangle mesh (z-buffer, Gouraud shading).

    Parameters
    ----------
    vertices : (n, 3) float, mm
    faces : (m, 3) int
    values : (n,) float, optional
        Per-vertex scalar coloured with ``cmap`` over [vmin, vmax]; else ``base_color``.
    size_px : (width, height)
    elevation_deg, azimuth_deg : float
        View direction (see :func:`camera_basis`).
    fit : (center (2,), px_per_mm), optional
        Screen placement; pass the same to several calls to render them at one
        scale. Default fits this mesh with a margin.
    supersample : int
        Samples per pixel side along the silhouette, whose pixels are covered in part
        (anti-aliased edges); one sample decides inside it.
    shadow : bool
        Soft shadow cast on the plane under the lowest point.
    contour_mm : float, optional
        Draw faint height contours this far apart (helps read the shape).
    hatch : (m,) bool, optional
        Faces striped in ``INVERTED`` (the regions that settled the other way up).

    Returns
    -------
    PIL.Image (RGBA, transparent background) and the ``fit`` used.
    """
    v = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    cam = camera_basis(elevation_deg, azimuth_deg)
    scr = project(v, cam)
    if fit is None:
        fit = view_fit([v], size_px, elevation_deg, azimuth_deg)
    (cx, cy), s = fit
    W, H = size_px
    ss = int(supersample)
    pxy = np.stack([W / 2 + (scr[:, 0] - cx) * s, H / 2 - (scr[:, 1] - cy) * s], 1)
    with np.errstate(invalid="ignore"):
        edges = edge_functions(pxy[faces])  # for both the z-buffer and the colour planes
    face, sample, cover = _coverage(pxy, scr[:, 2], faces, (H, W), ss, edges)
    idx = np.flatnonzero(face >= 0)  # flat pixel index: 1-D gathers are the fast ones
    rows, cols = np.divmod(idx, W)
    f = face.reshape(-1)[idx]
    L = _light(cam)
    rgb, shade = _vertex_colors(v, faces, cam, L, values, vmin, vmax, cmap, base_color)
    # Gouraud: the mesh's triangles are a few pixels across, so colours lit per vertex and
    # interpolated per pixel look the same as lighting every pixel, at a fraction of the work.
    attrs = [*rgb, v[:, 2], shade]
    planes = face_planes(pxy, faces, np.stack(attrs[:4 if hatch is None else 5]), edges)
    off = sample.reshape(-1, 2).take(idx, axis=0)
    ox, oy = off[:, 0], off[:, 1]
    x, y = cols + ox, rows + oy
    # One value (r, g, b, height, shade) at a time: contiguous rows, no (k, 5) arrays.
    at = [[planes[j, i].take(f) for i in range(3)] for j in range(len(planes))]
    val = [a * x + b * y + c for a, b, c in at]
    if contour_mm:
        # Contours from the height at the pixel centre: at the varying sample offsets
        # thin lines would come out dotted.
        z = val[3] + at[3][0] * (0.5 - ox) + at[3][1] * (0.5 - oy)
        darken = 1.0 - 0.28 * _contour_ink(z, at[3][0], at[3][1], contour_mm)
        for k in range(3):
            val[k] *= darken
    if hatch is not None:
        # Diagonal stripes keep the shading and the error colour readable between them.
        stripe = np.asarray(hatch, bool)[f] & ((rows + cols) // 3 % 3 == 0)
        lit = 0.55 + 0.45 * val[4][stripe]
        for k, q in enumerate(np.asarray(INVERTED, np.float32)):
            val[k][stripe] = q * lit
    img = np.zeros((H * W, 4), np.uint8)
    alpha = cover.reshape(-1)[idx]
    if shadow:
        sh = _shadow(v, faces, cam, L, (cx, cy), s, (H, W)).reshape(-1)
        img[:, 3] = sh
        alpha = alpha + (1.0 - alpha) * sh[idx] * np.float32(1 / 255)
    px = np.empty((len(idx), 4), np.uint8)
    for k in range(3):
        px[:, k] = np.clip(val[k] + 0.5, 0, 255)
    px[:, 3] = np.clip(255 * alpha + 0.5, 0, 255)
    img.view(np.uint32)[idx, 0] = px.view(np.uint32)[:, 0]  # whole RGBA pixels as 1-D items
    return Image.fromarray(img.reshape(H, W, 4), "RGBA"), fit


def _coverage(pxy, depth, faces, shape, ss, edges=None):
    """Which face each pixel shows, where to sample it, and how much of it is covered.

    pxy : (n, 2) px; depth : (n,); faces : (m, 3); shape : (H, W); ss : samples per
    pixel side; edges : :func:`edge_functions` of ``pxy[faces]``, optional. Returns face
    (H, W) int (-1 where nothing covers it), sample (H, W, 2) float32: the (x, y) offset
    within the pixel of a sample centre that face covers (sampling inside the face
    matters on the silhouette, where a face seen edge-on extrapolates to nonsense a
    fraction of a pixel outside it), and cover (H, W) float32 in [0, 1], the covered
    share of the pixel. Inside the silhouette a pixel is covered
    or not, so one sample at its centre decides; only the pixels along the silhouette
    (and the faces reaching them) are rasterised again at ``ss`` x for their coverage:
    a fraction of the work of rasterising the whole mesh at ``ss`` x.
    """
    H, W = shape
    fid = rasterize_triangles(pxy, depth, faces, shape, edges)
    covered = fid >= 0
    sample = np.full((H, W, 2), 0.5, np.float32)
    if ss == 1 or not covered.any():
        return fid, sample, covered.astype(np.float32)
    band = _silhouette_band(covered)
    near = np.flatnonzero(_faces_reaching(pxy, faces, band))
    fid2 = rasterize_triangles(pxy * ss, depth, faces[near], (H * ss, W * ss))
    r, c = np.nonzero(band)
    sub = fid2.reshape(H, ss, W, ss)[r, :, c, :].reshape(len(r), ss * ss)
    hit = sub >= 0
    first = np.argmax(hit, axis=1)
    cover = covered.astype(np.float32)
    cover[r, c] = hit.sum(axis=1) / np.float32(ss * ss)
    # A band pixel whose centre misses the mesh shows the face of its first covered sample.
    miss = ~covered[r, c] & hit.any(axis=1)
    r, c, first = r[miss], c[miss], first[miss]
    fid[r, c] = near[sub[miss, first]]
    sample[r, c, 0] = (first % ss + 0.5) / ss
    sample[r, c, 1] = (first // ss + 0.5) / ss
    return fid, sample, cover


def _silhouette_band(covered):
    """Pixels (H, W) bool with both covered and uncovered pixels among their 3 x 3."""
    pad = np.pad(covered, 1)
    H, W = covered.shape
    any_ = np.zeros_like(covered)
    all_ = np.ones_like(covered)
    for dy in range(3):
        for dx in range(3):
            q = pad[dy:dy + H, dx:dx + W]
            any_ |= q
            all_ &= q
    return any_ & ~all_


def _faces_reaching(pxy, faces, mask):
    """(m,) bool: faces whose pixel box overlaps a pixel of ``mask`` (H, W) bool, by a
    summed-area table (one lookup per face)."""
    H, W = mask.shape
    sat = np.zeros((H + 1, W + 1), np.int32)
    sat[1:, 1:] = mask.cumsum(0, dtype=np.int32).cumsum(1, dtype=np.int32)
    box = []
    for k in range(2):
        q = pxy[:, k][faces]  # (m, 3); NaN corners give an empty box
        lo = np.floor(np.minimum(np.minimum(q[:, 0], q[:, 1]), q[:, 2]))
        hi = np.floor(np.maximum(np.maximum(q[:, 0], q[:, 1]), q[:, 2])) + 1
        with np.errstate(invalid="ignore"):
            box += [np.clip(np.nan_to_num(lo, nan=0.0), 0, mask.shape[1 - k]).astype(np.int64),
                    np.clip(np.nan_to_num(hi, nan=0.0), 0, mask.shape[1 - k]).astype(np.int64)]
    x0, x1, y0, y1 = box
    # Flat indices into the table: 1-D takes are several times faster than 2-D indexing.
    at = lambda y, x: sat.take(y * (W + 1) + x)
    n = at(y1, x1) - at(y0, x1) - at(y1, x0) + at(y0, x0)
    return (n > 0) & (x1 > x0) & (y1 > y0)


def _vertex_colors(v, faces, cam, L, values, vmin, vmax, cmap, base_color):
    """Lit colour per vertex: Lambert key light, sky fill, Blinn-Phong highlight.

    Returns rgb, three (n,) float (0-255, before clipping), and the shade factor (n,)
    float. Column by column: (n, 3) arithmetic with a per-vertex factor loops per vertex.
    """
    nx, ny, nz = _vertex_normals(v, faces)
    dot = lambda r: nx * r[0] + ny * r[1] + nz * r[2]
    # Two-sided: a normal facing away from the camera belongs to the hidden side.
    flip = np.where(dot(cam[2]) > 0, -1.0, 1.0)
    nx, ny, nz = nx * flip, ny * flip, nz * flip
    Hv = L - cam[2]
    Hv /= np.linalg.norm(Hv)
    diff = np.clip(dot(L), 0, 1)
    fill = 0.5 * (1 + nz)  # sky light: surfaces looking up get more
    spec = np.clip(dot(Hv), 0, 1) ** 48
    if values is None:
        base = np.asarray(base_color, np.float64)[None, :]
    else:
        base = colormap(np.asarray(values, np.float64), vmin, vmax, cmap).astype(np.float64)
    shade = 0.22 + 0.16 * fill + 0.68 * diff
    return [base[:, c] * shade + 55.0 * spec for c in range(3)], shade


def _contour_ink(z, gx, gy, step, width_px=0.5):
    """Anti-aliased contour lines every ``step`` mm: ink (k,) float32 in [0, 1].

    z : (k,) heights (mm) at pixel centres; gx, gy : (k,) their change per pixel in x and
    y. The distance to the nearest level in pixels is the height difference over the slope.
    """
    q = z / step
    dist = np.abs(q - np.round(q)) * step / np.maximum(np.hypot(gx, gy), 1e-12)
    return np.clip(0.5 * width_px + 0.5 - dist, 0.0, 1.0).astype(np.float32)


def _shadow(v, faces, cam, L, center, s, shape, k=4):
    """Alpha (uint8, ``shape``) of a soft shadow: the mesh projected along the
    light onto its base plane, drawn at 1/k resolution since it is blurred."""
    z0 = v[:, 2].min()
    d = (v[:, 2] - z0) / max(L[2], 0.2)
    g = [v[:, j] - d * L[j] for j in range(3)]  # columns: no (n, 3) broadcasting
    sx, sy = (g[0] * r[0] + g[1] * r[1] + g[2] * r[2] for r in cam[:2])  # as project()
    H, W = shape
    h, w = H // k, W // k
    pxy = np.stack([w / 2 + (sx - center[0]) * s / k, h / 2 - (sy - center[1]) * s / k], 1)
    # Dense meshes: splatting the vertices covers the footprint; faces wider
    # than a pixel are rasterised so coarse meshes have no holes.
    c = np.floor(pxy).astype(np.int64)
    inb = (c[:, 0] >= 0) & (c[:, 0] < w) & (c[:, 1] >= 0) & (c[:, 1] < h)
    mask = np.zeros((h, w), bool)
    mask[c[inb, 1], c[inb, 0]] = True
    ext = np.zeros(len(faces))
    for k in range(2):
        q = pxy[:, k][faces]
        ext = np.maximum(ext, np.maximum(np.maximum(q[:, 0], q[:, 1]), q[:, 2])
                         - np.minimum(np.minimum(q[:, 0], q[:, 1]), q[:, 2]))
    big = faces[ext > 1.0]
    if len(big):
        mask |= rasterize_triangles(pxy, np.zeros(len(pxy)), big, (h, w), coverage=True)
    m = Image.fromarray(np.where(mask, 70, 0).astype(np.uint8))
    m = m.filter(ImageFilter.GaussianBlur(max(2.0, 0.012 * w)))
    return np.asarray(m.resize((W, H), Image.BILINEAR))


def view_fit(vertex_sets, size_px, elevation_deg=35.0, azimuth_deg=-30.0, margin=0.08):
    """Screen centre and px/mm that fit all ``vertex_sets`` ((n, 3) mm each) into ``size_px``."""
    cam = camera_basis(elevation_deg, azimuth_deg)
    scr = np.concatenate([project(np.asarray(v, np.float64), cam) for v in vertex_sets])
    lo, hi = extent(scr[:, :2])
    span = np.maximum(hi - lo, 1e-9)
    s = min(size_px[0] * (1 - 2 * margin) / span[0], size_px[1] * (1 - 2 * margin) / span[1])
    return (0.5 * (lo + hi)), s
