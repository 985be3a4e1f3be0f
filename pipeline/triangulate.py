"""Triangulating the cells of the isoline/gradient-line graph (paper 6.1, Fig. 5c-d).

Cells between two isolines are zipped greedily by the shortest diagonal;
polygons at peaks and saddles are fanned around an inserted centre vertex,
with ear clipping as the fallback where a fan would fold over itself.
"""

import mapbox_earcut
import numpy as np


def zip_strips(points, lowers, uppers):
    """Greedy shortest-diagonal triangulation of strips between two chains.

    Each strip is bounded by chain ``L`` (walked forward along the cell's
    counter-clockwise boundary) and chain ``U`` (walked backward), with the
    rungs ``(L[0], U[0])`` and ``(L[-1], U[-1])`` on the cell boundary.

    Parameters
    ----------
    points : (n, 3) float, mm (distances are measured on the target surface)
    lowers, uppers : list of (k_i,) int vertex ids, one pair per strip

    Returns
    -------
    faces : (m, 3) int, counter-clockwise when the cells are.
    strip : (m,) int, the strip each face belongs to.
    """
    if not lowers:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    nl = np.array([len(a) for a in lowers])
    nu = np.array([len(a) for a in uppers])
    L = _pad(lowers, nl.max())
    U = _pad(uppers, nu.max())
    i = np.zeros(len(nl), dtype=np.int64)
    j = np.zeros(len(nu), dtype=np.int64)
    out = []
    owner = []
    active = np.nonzero((nl > 1) | (nu > 1))[0]
    while len(active):
        ia, ja = i[active], j[active]
        can_l = ia < nl[active] - 1
        can_u = ja < nu[active] - 1
        li, lj = L[active, ia], U[active, ja]
        l_next = L[active, np.minimum(ia + 1, nl[active] - 1)]
        u_next = U[active, np.minimum(ja + 1, nu[active] - 1)]
        d_l = _d2(points, l_next, lj)
        d_u = _d2(points, li, u_next)
        # Shortest diagonal, unless it would fold the triangle over in the plane.
        ok_l = _area2(points, li, l_next, lj) > 0
        ok_u = _area2(points, li, u_next, lj) > 0
        prefer_l = np.where(ok_l == ok_u, d_l <= d_u, ok_l)
        take_l = can_l & (~can_u | prefer_l)
        take_u = can_u & ~take_l
        out.append(np.stack([li, l_next, lj], axis=1)[take_l])
        out.append(np.stack([li, u_next, lj], axis=1)[take_u])
        owner.append(active[take_l])
        owner.append(active[take_u])
        i[active] += take_l
        j[active] += take_u
        active = active[(i[active] < nl[active] - 1) | (j[active] < nu[active] - 1)]
    if not out:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(out), np.concatenate(owner)


def _pad(chains, width):
    m = np.zeros((len(chains), width), dtype=np.int64)
    for r, c in enumerate(chains):
        m[r, :len(c)] = c
    return m


def _area2(points, a, b, c):
    p, q, r = points[a], points[b], points[c]
    return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])


def _d2(points, a, b):
    d = points[a] - points[b]
    return np.einsum("ij,ij->i", d, d)


def fan(xy, ring, centre_id, centre_xy):
    """Fan triangles ``(centre, ring[k], ring[k+1])`` or None if any would fold.

    xy : (n, 2) float, vertex positions; ring : (k,) int, a counter-clockwise cycle.
    """
    a = xy[ring] - centre_xy
    b = np.roll(xy[ring], -1, axis=0) - centre_xy
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    if np.any(cross <= 1e-12):
        return None
    return np.stack([np.full(len(ring), centre_id), ring, np.roll(ring, -1)], axis=1)


def ear_clip(xy, ring):
    """Triangulate a simple polygon (counter-clockwise ``ring`` of vertex ids)."""
    coords = np.ascontiguousarray(xy[ring], dtype=np.float64)
    tri = mapbox_earcut.triangulate_float64(coords, np.array([len(ring)], dtype=np.uint32))
    tri = ring[np.asarray(tri, dtype=np.int64).reshape(-1, 3)]
    p = xy[tri]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - \
        (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])
    tri[area < 0] = tri[area < 0][:, [0, 2, 1]]
    return tri
