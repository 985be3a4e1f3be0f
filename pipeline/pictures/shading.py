"""Shaded 3-D views of triangle meshes (numpy + Pillow): orthographic camera, z-buffer,
per-pixel normals, Lambert + Blinn-Phong light, soft ground shadow, height contours.

Used by :func:`pipeline.pictures.render.preview_image`; usable on its own for thumbnails.
"""

import numpy as np
from PIL import Image, ImageFilter

from pipeline.pictures.figure import INVERTED, colormap
from pipeline.pictures.raster import pixel_barycentrics, rasterize_triangles


def _vertex_normals(vertices, faces):
    """Area-weighted unit vertex normals: (n, 3)."""
    v = vertices[faces]
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n = np.stack([np.bincount(faces.ravel(), np.repeat(fn[:, k], 3), minlength=len(vertices))
                  for k in range(3)], axis=1)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


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
    """Shaded orthographic render of a triangle mesh (z-buffer, per-pixel normals).

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
        Render at this factor and box-filter down (anti-aliased silhouettes).
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
    Ws, Hs = W * ss, H * ss
    pxy = np.stack([Ws / 2 + (scr[:, 0] - cx) * s * ss, Hs / 2 - (scr[:, 1] - cy) * s * ss], 1)
    fid = rasterize_triangles(pxy, scr[:, 2], faces, (Hs, Ws))
    rows, cols, f, w = pixel_barycentrics(pxy, faces, fid)
    vn = _vertex_normals(v, faces).astype(np.float32)
    w = w.astype(np.float32)
    fv = faces[f]
    n = (w[:, 0:1] * vn[fv[:, 0]] + w[:, 1:2] * vn[fv[:, 1]] + w[:, 2:3] * vn[fv[:, 2]])
    n /= np.maximum(np.sqrt(n[:, 0] ** 2 + n[:, 1] ** 2 + n[:, 2] ** 2), 1e-12)[:, None]
    # Two-sided: a normal facing away from the camera belongs to the hidden side.
    n *= np.where(project(n, cam[2:3])[:, 0] > 0, -1.0, 1.0).astype(np.float32)[:, None]
    L = _light(cam)
    Hv = L - cam[2]
    Hv /= np.linalg.norm(Hv)
    diff = np.clip(project(n, L[None])[:, 0], 0, 1)
    fill = 0.5 * (1 + n[:, 2])  # sky light: surfaces looking up get more
    spec = np.clip(project(n, Hv[None])[:, 0], 0, 1) ** 48
    if values is None:
        base = np.asarray(base_color, np.float32)[None, :]
    else:
        val = (w * np.asarray(values, np.float32)[fv]).sum(1)
        base = colormap(val, vmin, vmax, cmap).astype(np.float32)
    shade = 0.22 + 0.16 * fill + 0.68 * diff
    rgb = base * shade[:, None] + 55.0 * spec[:, None]
    if contour_mm:
        # A contour pixel is one whose height band differs from its right or lower neighbour.
        band = np.full((Hs + 1, Ws + 1), np.iinfo(np.int32).min, np.int32)
        band[rows, cols] = np.floor((w * v[fv, 2].astype(np.float32)).sum(1) / contour_mm)
        b0 = band[rows, cols]
        right, below = band[rows, cols + 1], band[rows + 1, cols]
        edge = ((right != b0) & (right != np.iinfo(np.int32).min)) | \
               ((below != b0) & (below != np.iinfo(np.int32).min))
        rgb[edge] *= 0.72
    if hatch is not None:
        # Diagonal stripes keep the shading and the error colour readable between them.
        stripe = np.asarray(hatch, bool)[f] & ((rows + cols) // (3 * ss) % 3 == 0)
        rgb[stripe] = np.asarray(INVERTED, np.float32) * (0.55 + 0.45 * shade[stripe, None])
    img = np.zeros((Hs, Ws, 4), np.uint8)
    if shadow:
        img[..., 3] = _shadow(v, faces, cam, L, (cx, cy), s * ss, (Hs, Ws))
    img[rows, cols, :3] = np.clip(rgb + 0.5, 0, 255).astype(np.uint8)
    img[rows, cols, 3] = 255
    out = Image.fromarray(img, "RGBA")
    if ss > 1:
        out = out.reduce(ss)
    return out, fit


def _shadow(v, faces, cam, L, center, s, shape, k=4):
    """Alpha (uint8, ``shape``) of a soft shadow: the mesh projected along the
    light onto its base plane, drawn at 1/k resolution since it is blurred."""
    z0 = v[:, 2].min()
    g = v - ((v[:, 2] - z0) / max(L[2], 0.2))[:, None] * L
    scr = project(g, cam)
    H, W = shape
    h, w = H // k, W // k
    pxy = np.stack([w / 2 + (scr[:, 0] - center[0]) * s / k, h / 2 - (scr[:, 1] - center[1]) * s / k], 1)
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
        mask |= rasterize_triangles(pxy, np.zeros(len(pxy)), big, (h, w)) >= 0
    m = Image.fromarray(np.where(mask, 70, 0).astype(np.uint8))
    m = m.filter(ImageFilter.GaussianBlur(max(2.0, 0.012 * w)))
    return np.asarray(m.resize((W, H), Image.BILINEAR))


def view_fit(vertex_sets, size_px, elevation_deg=35.0, azimuth_deg=-30.0, margin=0.08):
    """Screen centre and px/mm that fit all ``vertex_sets`` ((n, 3) mm each) into ``size_px``."""
    cam = camera_basis(elevation_deg, azimuth_deg)
    scr = np.concatenate([project(np.asarray(v, np.float64), cam) for v in vertex_sets])
    lo, hi = scr[:, :2].min(0), scr[:, :2].max(0)
    span = np.maximum(hi - lo, 1e-9)
    s = min(size_px[0] * (1 - 2 * margin) / span[0], size_px[1] * (1 - 2 * margin) / span[1])
    return (0.5 * (lo + hi)), s
