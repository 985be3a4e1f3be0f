"""A plain triangulation of a height field over its footprint, for layouts that need no
isoline graph (the free-direction method).

A regular grid of ``spacing_mm``, each square cut along alternating diagonals (so the
mesh has no preferred direction), keeping the triangles whose corners and centre lie on
the footprint; heights are read from the field by bilinear interpolation. Any footprint
and any terrain mesh this way: no isoline can cross another, so nothing can overlap.

The kept squares end in a staircase where the footprint's edge runs across the grid,
and the stripe paths cut that staircase into stubs a millimetre long, each printed on
its own (a dome's sheet took 125 separate traces for one spiral). So the boundary
vertices are moved onto the footprint's edge, and the slivers that leaves squashed
flat against it are dropped.
"""

import numpy as np
from scipy.ndimage import map_coordinates

from pipeline.errors import MeshingError
from pipeline.geometry import Mesh

_PAD = 4


def build_grid_mesh(hf, spacing_mm=1.0):
    """Triangulate ``hf`` (a validated :class:`HeightField`) on a regular grid.

    Returns a :class:`Mesh` with every edge a bridge edge (no printing edges: the
    layout chooses the print direction) and ``vertex_level`` the vertices' heights.
    """
    z = np.asarray(hf.z, dtype=float)
    inside = np.isfinite(z)
    rows, cols = z.shape
    px = float(hf.pixel_mm)
    width, height = (cols - 1) * px, (rows - 1) * px
    nx = max(int(np.floor(width / spacing_mm)), 1) + 1
    ny = max(int(np.floor(height / spacing_mm)), 1) + 1
    xs = np.linspace(0.0, width, nx)
    ys = np.linspace(0.0, height, ny)
    X, Y = np.meshgrid(xs, ys)
    pts = np.c_[X.ravel(), Y.ravel()]
    ok = _on_footprint(hf, inside, pts)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    flip = ((np.arange(ny - 1)[:, None] + np.arange(nx - 1)[None, :]) % 2).ravel().astype(bool)
    # Counter-clockwise seen from +z (y grows with the row index here).
    t1 = np.where(flip[:, None], np.c_[a, b, d], np.c_[a, b, c])
    t2 = np.where(flip[:, None], np.c_[a, d, c], np.c_[b, d, c])
    faces = np.concatenate([t1, t2])
    centre = pts[faces].mean(axis=1)
    keep = ok[faces].all(axis=1) & _on_footprint(hf, inside, centre)
    faces = faces[keep]
    if len(faces) == 0:
        raise MeshingError("the footprint is narrower than the mesh spacing (%.3g mm)"
                           % spacing_mm, code="mesh.too_small",
                           fix="make the part larger (size_mm) or lower mesh.grid_mm")
    xy, faces = _compact(pts, faces)
    xy, faces = _compact(xy, _one_piece(faces))
    xy, faces = follow_edge(hf, inside, xy, faces, spacing_mm)
    zz = _heights(hf, z, inside, xy)
    V = np.c_[xy, zz]
    from pipeline.geometry import unique_edges
    return Mesh(vertices=V, faces=faces, printing_edges=np.zeros((0, 2), np.int64),
                bridge_edges=unique_edges(faces), vertex_level=zz,
                printing_isoline=np.zeros(0, np.int64),
                info={"method": "grid", "grid_mm": float(spacing_mm)})


def follow_edge(hf, inside, xy, faces, spacing_mm):
    """The mesh ``xy`` ((n, 2) mm), ``faces`` ((m, 3)) with its boundary vertices moved
    onto the footprint's edge (the line through the outermost footprint pixels'
    centres, as a straight edge of the grid already lies) where no triangle turns over
    for it; triangles with all corners on the edge squashed to less than a quarter of a
    grid triangle are dropped. Returns (xy, faces), the vertices renumbered."""
    from pipeline.geometry import boundary_loops, signed_areas_2d
    sdf, grad = _edge_distance(inside, float(hf.pixel_mm))
    b = np.unique(np.concatenate(boundary_loops(faces)))
    moved = xy.copy()
    for _ in range(3):                       # Newton steps on the distance to the edge
        rc = np.stack(hf.rc(moved[b]), axis=0) + _PAD
        s = map_coordinates(sdf, rc, order=1, mode="nearest")
        g = np.stack([map_coordinates(grad[k], rc, order=1, mode="nearest")
                      for k in range(2)], axis=1)
        moved[b] -= s[:, None] * g / np.maximum((g * g).sum(axis=1), 1e-6)[:, None]
    # A step never goes farther than the edge can be from a kept corner.
    step = moved[b] - xy[b]
    far = np.linalg.norm(step, axis=1) > 1.5 * spacing_mm
    moved[b[far]] = xy[b[far]]
    nominal = 0.5 * spacing_mm ** 2
    on_edge = np.zeros(len(xy), bool)
    on_edge[b] = True
    for _ in range(5):
        area = signed_areas_2d(moved, faces)
        flat = (area < 0.25 * nominal) & on_edge[faces].all(axis=1)
        faces = faces[~flat]
        bad = signed_areas_2d(moved, faces) < 0.1 * nominal
        if not bad.any():
            break
        # Where a triangle would turn over or squash, its corners stay on the grid.
        back = np.unique(faces[bad])
        moved[back] = xy[back]
    return _compact(moved, _one_piece(faces))


def _compact(xy, faces):
    """Only the vertices ``faces`` use, renumbered in order: (xy, faces)."""
    used = np.unique(faces)
    remap = np.full(len(xy), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return xy[used], remap[faces]


def _edge_distance(inside, px):
    """Signed distance (mm) to the footprint's edge, zero at the outermost footprint
    pixels' centres and positive inside, smoothed over a pixel so the pixels' own
    staircase does not show, and its gradient in plane coordinates ((2,) + shape, mm
    per mm, x then y); both padded by ``_PAD`` pixels all round, so that the edge of
    the image is an edge like any other."""
    from scipy.ndimage import distance_transform_edt, gaussian_filter
    pad = np.pad(inside, _PAD)
    d = np.where(pad, distance_transform_edt(pad) - 1.0, -distance_transform_edt(~pad))
    d = gaussian_filter(d * px, 1.0, mode="nearest")
    g_row, g_col = np.gradient(d, px)
    # Rows run against y (see HeightField.rc).
    return d, np.stack([g_col, -g_row])


def _on_footprint(hf, inside, pts):
    r, c = hf.rc(pts)
    ri = np.clip(np.rint(r).astype(int), 0, inside.shape[0] - 1)
    ci = np.clip(np.rint(c).astype(int), 0, inside.shape[1] - 1)
    return inside[ri, ci]


def _heights(hf, z, inside, xy):
    """Bilinear heights at ``xy``; samples next to the outside use the nearest inside one."""
    from scipy.ndimage import distance_transform_edt
    filled = z[tuple(distance_transform_edt(~inside, return_distances=False,
                                            return_indices=True))]
    r, c = hf.rc(xy)
    return map_coordinates(filled, [r, c], order=1, mode="nearest")


def _one_piece(faces):
    """The faces of the largest edge-connected piece (a footprint pinched at a grid
    corner would otherwise give a sheet of two pieces)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    m = len(faces)
    he = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(m), 3)
    key = he[:, 0] * (faces.max() + 1) + he[:, 1]
    order = np.argsort(key, kind="stable")
    k, o = key[order], owner[order]
    same = np.flatnonzero(k[1:] == k[:-1])
    adj = coo_matrix((np.ones(len(same)), (o[same], o[same + 1])), shape=(m, m))
    n, label = connected_components(adj, directed=False)
    if n == 1:
        return faces
    big = np.argmax(np.bincount(label))
    return faces[label == big]
