"""The isoline method's sheet on a plain grid, for the thin-shell simulation.

The isoline mesh is built for the layout: printing edges a quarter millimetre long
between isolines a millimetre apart, triangles four times longer than wide. A thin
shell on such triangles is stiff in the wrong places and its solver crawls. The
printed sheet does not care how the layout was meshed: every point of it shrinks
along the isoline through it by the sigma the layout gives there. So the sheet is
resampled onto the regular grid the free method simulates on, each grid triangle
printing along the isolines (``d``) with the shrink of the layout's map along ``d``.
A sheet so resampled settles where the isoline mesh's own does (tests).
"""

from dataclasses import dataclass

import numpy as np
import shapely

from pipeline.layout.curvature import isoline_directions
from pipeline.meshing.grid import build_grid_mesh


@dataclass
class GridSheet:
    """The sheet on a grid.

    vertices : (n, 3) mm, the target at the grid points; faces : (m, 3) int;
    xy : (n, 2) mm, where the layout puts them; direction : (m, 2) unit, the print
    direction in the layout; sigma : (m,) the shrink along it (not clamped).
    """

    vertices: np.ndarray
    faces: np.ndarray
    xy: np.ndarray
    direction: np.ndarray
    sigma: np.ndarray


def onto_grid(hf, mesh, xy, spacing_mm):
    """Resample the layout ``xy`` ((n, 2) mm) of ``mesh`` onto a grid of ``hf`` every
    ``spacing_mm``: :class:`GridSheet`."""
    grid = build_grid_mesh(hf, spacing_mm)
    G = np.asarray(grid.vertices, dtype=float)
    gxy = _carry(np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces), np.asarray(xy,
                 dtype=float), G[:, :2])
    faces = np.asarray(grid.faces, dtype=np.int64)
    d = isoline_directions(gxy, faces, G[:, 2])
    return GridSheet(vertices=G, faces=faces, xy=gxy, direction=d,
                     sigma=1.0 - _stretch_along(G, gxy, faces, d))


def _carry(V, faces, xy, points):
    """Where the piecewise-linear map target (x, y) -> layout takes ``points`` ((k, 2)):
    inside the triangle that holds each, or by the nearest triangle's map beyond
    the mesh's edge. Returns (k, 2) mm."""
    which, bary = locate(np.asarray(V)[:, :2], faces, points)
    return np.einsum("kj,kjc->kc", bary, xy[faces[which]])


def _stretch_along(V, xy, faces, d):
    """Length on the target of a unit step along ``d`` in the layout, per triangle."""
    P, T = xy[faces], V[faces]
    flat = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]], axis=2)       # (m, 2, 2)
    target = np.stack([T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]], axis=2)     # (m, 3, 2)
    coef = np.linalg.solve(flat, d[:, :, None])[:, :, 0]
    return np.linalg.norm(np.einsum("fij,fj->fi", target, coef), axis=1)


def locate(V2, faces, points):
    """The triangle of ``faces`` (over ``V2``, (n, 2) mm) holding each of ``points``
    ((k, 2) mm), or the nearest one, and the points' barycentric coordinates in it:
    ((k,) int, (k, 3))."""
    T = V2[faces]
    tree = shapely.STRtree(shapely.polygons(np.concatenate([T, T[:, :1]], axis=1)))
    pts = shapely.points(points)
    which = np.full(len(points), -1, dtype=np.int64)
    hit = tree.query(pts, predicate="intersects")
    which[hit[0]] = hit[1]
    lost = np.flatnonzero(which < 0)
    if len(lost):
        near = tree.query_nearest(pts[lost], return_distance=False)
        which[lost[near[0]]] = near[1]
    a, b, c = (T[which, k] for k in range(3))
    uv = np.linalg.solve(np.stack([b - a, c - a], axis=2), (points - a)[:, :, None])[:, :, 0]
    return which, np.c_[1.0 - uv.sum(axis=1), uv]
