"""Mesh topology and the local projections of the sheet constraints (paper 6.2.1).

Index structure (edges, hinges, corners) computed once per mesh, intrinsic
triangle quantities from edge lengths, the cotangent hinge rows of the
bending constraint, and the vectorised Euclidean projections of the edge
strain and corner shear constraints. Vectors are component-major, (d, k).
Used by :mod:`pipeline.mechanics.pd`.
"""

from dataclasses import dataclass

import numpy as np

# Bounds of the hinge rows: cot(1 degree), and a fraction of the median face area.
_MAX_COT = 57.3
_MIN_AREA_FRACTION = 0.05
# Hinges with a triangle whose smallest corner is below this get no bending row.
# There the cotangent row measures discretisation error, not curvature: on the
# saddle mesh 1 % of the hinges (caps and needles in wide cells near the
# saddle, angles of 0.2-0.6 degrees) held 97 % of the target's bending energy,
# enough to keep the simulated sheet 5.7 % of its diameter off the target
# (0.9 % without them). A dome's apex fan (1.3 degree corners) keeps its rows.
_MIN_HINGE_ANGLE_DEG = 1.0

# Rest triangles are kept at least this fat (area / sum of squared sides) so
# that inconsistent rest lengths (a bridge strained past the triangle
# inequality) give bounded cotangents instead of an ill-conditioned system.
_MIN_FATNESS = 1e-4


def row_lengths(rest_len, floor_fraction=0.1):
    """Lengths that scale constraint rows (1/sqrt(l)): (e,) mm.

    Rest lengths, but never below ``floor_fraction`` of the median: a
    near-zero edge (a mesher's sliver) would otherwise get a row weight that
    wrecks the conditioning of the whole system.
    """
    rest_len = np.asarray(rest_len, dtype=float)
    return np.maximum(rest_len, floor_fraction * float(np.median(rest_len)))


@dataclass
class Topology:
    """Index structure of a triangle mesh, computed once.

    Attributes
    ----------
    n : int
        Vertex count.
    faces : (m, 3) int
    edges : (e, 2) int
        Unique sorted edges.
    face_edge : (m, 3) int
        Edge index opposite each face corner.
    edge_faces : (e, 2) int
        Incident faces of each edge; -1 for the missing one on the boundary.
    hinges : (h, 4) int
        Interior edges as (v0, v1, v2, v3): edge v0-v1, v2 opposite in the
        face where the edge runs v0->v1, v3 opposite in the other face.
    hinge_faces : (h, 2) int
    hinge_edge : (h,) int
    boundary_edges : (b,) int
        Indices into ``edges`` with one incident face.
    """

    n: int
    faces: np.ndarray
    edges: np.ndarray
    face_edge: np.ndarray
    edge_faces: np.ndarray
    hinges: np.ndarray
    hinge_faces: np.ndarray
    hinge_edge: np.ndarray
    boundary_edges: np.ndarray

    @property
    def boundary_vertices(self):
        """(k,) int: vertices on boundary edges."""
        return np.unique(self.edges[self.boundary_edges])


def topology(faces, n=None):
    """Build the :class:`Topology` of ``faces`` ((m, 3) int, consistently oriented)."""
    faces = np.asarray(faces, dtype=np.int64)
    m = len(faces)
    n = int(faces.max()) + 1 if n is None else int(n)
    # Half-edge (f, k) runs faces[f, k] -> faces[f, k+1]; it is opposite corner k+2.
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * n + hi
    edge_key, inverse = np.unique(key, return_inverse=True)
    edges = np.stack([edge_key // n, edge_key % n], axis=1)
    he_edge = inverse.reshape(m, 3)
    face_edge = he_edge[:, [1, 2, 0]]  # corner k is opposite half-edge k+1
    # Two incident faces per edge: the half-edge running lo->hi first.
    forward = (a < b)
    he_face = np.repeat(np.arange(m), 3)
    edge_faces = np.full((len(edges), 2), -1, dtype=np.int64)
    edge_faces[inverse[forward], 0] = he_face[forward]
    edge_faces[inverse[~forward], 1] = he_face[~forward]
    counts = np.bincount(inverse, minlength=len(edges))
    if counts.max(initial=0) > 2:
        raise ValueError("non-manifold mesh: an edge has more than two faces")
    boundary = np.flatnonzero(counts == 1)
    # A boundary edge may have only its reversed half-edge: keep its face in slot 0.
    only_back = (edge_faces[:, 0] < 0) & (edge_faces[:, 1] >= 0)
    edge_faces[only_back] = edge_faces[only_back][:, ::-1]
    interior = np.flatnonzero((edge_faces[:, 0] >= 0) & (edge_faces[:, 1] >= 0))
    f0, f1 = edge_faces[interior, 0], edge_faces[interior, 1]
    v0, v1 = edges[interior, 0], edges[interior, 1]
    hinges = np.stack([v0, v1, _opposite(faces, f0, v0, v1), _opposite(faces, f1, v0, v1)], axis=1)
    return Topology(n, faces, edges, face_edge, edge_faces, hinges,
                    np.stack([f0, f1], axis=1), interior, boundary)


def _opposite(faces, f, u, v):
    """Vertex of face ``f`` that is neither ``u`` nor ``v`` (vectorised)."""
    tri = faces[f]
    keep = (tri != u[:, None]) & (tri != v[:, None])
    return tri[np.arange(len(f)), np.argmax(keep, axis=1)]


def face_geometry(top, edge_len):
    """Intrinsic triangle quantities from edge lengths alone.

    Parameters
    ----------
    top : Topology
    edge_len : (e,) float, mm

    Returns
    -------
    area : (m,) float, mm^2 (Heron; kept above a small fraction of the
        squared sides, see ``_MIN_FATNESS``)
    cot : (m, 3) float, cotangent of the angle at each corner
    angle : (m, 3) float, rad, angle at each corner
    """
    l2 = edge_len[top.face_edge] ** 2  # squared length opposite each corner
    a, b, c = np.sqrt(l2[:, 0]), np.sqrt(l2[:, 1]), np.sqrt(l2[:, 2])
    prod = (a + b + c) * (-a + b + c) * (a - b + c) * (a + b - c)
    area = 0.25 * np.sqrt(np.maximum(prod, 0.0))
    area = np.maximum(area, _MIN_FATNESS * l2.sum(axis=1) + 1e-300)
    # Law of cosines: at corner k, 2 |e1||e2| cos = l2[k+1] + l2[k+2] - l2[k].
    num = l2[:, [1, 2, 0]] + l2[:, [2, 0, 1]] - l2
    cot = num / (4.0 * area[:, None])
    angle = np.arctan2(4.0 * area[:, None], num)
    return area, cot, angle


def hinge_weights(top, edge_len):
    """Scaled cotangent hinge rows ``sqrt(3/(A0+A1)) K0``: (h, 4) float, 1/mm.

    K0 = (c03 + c04, c01 + c02, -c01 - c03, -c02 - c04) of Wardetzky et al.
    (isometric discrete bending), for hinge vertices ordered as in
    :attr:`Topology.hinges`; built from edge lengths so it needs no embedding.
    Rows of hinges beside a triangle with a corner below
    ``_MIN_HINGE_ANGLE_DEG`` are zero (see there).
    """
    area, cot, angle = face_geometry(top, edge_len)
    degenerate = np.degrees(angle.min(axis=1)) < _MIN_HINGE_ANGLE_DEG
    # Slivers (real-terrain meshes have corners below 0.1 degree) would give
    # rows thousands of times the typical one: bound the cotangents and the
    # area a hinge may be divided by.
    cot = np.clip(cot, -_MAX_COT, _MAX_COT)
    area = np.maximum(area, _MIN_AREA_FRACTION * float(np.median(area)))
    f0, f1 = top.hinge_faces[:, 0], top.hinge_faces[:, 1]
    v0, v1 = top.hinges[:, 0], top.hinges[:, 1]
    c0_f0 = _corner_value(top.faces, cot, f0, v0)
    c1_f0 = _corner_value(top.faces, cot, f0, v1)
    c0_f1 = _corner_value(top.faces, cot, f1, v0)
    c1_f1 = _corner_value(top.faces, cot, f1, v1)
    k = np.stack([c1_f0 + c1_f1, c0_f0 + c0_f1, -(c0_f0 + c1_f0), -(c0_f1 + c1_f1)], axis=1)
    k *= np.sqrt(3.0 / (area[f0] + area[f1]))[:, None]
    k[degenerate[f0] | degenerate[f1]] = 0.0
    return k


def _corner_value(faces, values, f, v):
    """``values[f, k]`` where ``faces[f, k] == v`` (vectorised)."""
    k = np.argmax(faces[f] == v[:, None], axis=1)
    return values[f, k]


def project_edges(Y, lo, hi, return_residual=False):
    """Closest vectors with length in [lo, hi] (same direction): (d, k) -> (d, k).

    A zero vector has no direction; it is sent along +x (any choice is closest).
    With ``return_residual`` also returns |Y - P|^2 per vector ((k,)).
    """
    length = np.sqrt(np.einsum("ij,ij->j", Y, Y))
    target = np.clip(length, lo, hi)
    safe = length > 0
    P = Y * np.where(safe, target / np.where(safe, length, 1.0), 0.0)
    if not safe.all():
        P[0, ~safe] = target[~safe]
    if return_residual:
        return P, (length - target) ** 2
    return P


def project_corners(U0, U1, cos0, sin0, planar=False, return_residual=False):
    """Closest pair of vectors whose angle is theta0 (given as cos0, sin0, (k,)).

    Within the plane of U0, U1 ((d, k), d = 2 or 3), rotating U0 by -a0 and
    U1 by +a1 (a0 + a1 = delta = theta0 - theta) and scaling each by cos(a_i)
    (dropping it perpendicularly onto its new line) costs
    |U0|^2 sin^2 a0 + |U1|^2 sin^2 a1, minimised by
    2 a0 = arg(|U0|^2 + |U1|^2 exp(2 i delta)): a symmetric rotation for equal
    lengths, lengths changed only to second order. That is the Euclidean
    projection, which keeps PD's energy monotone. It is evaluated without
    trigonometry: the rotated vectors are combinations of U0 and U1.

    Where the angle is off by more than 90 degrees (flipped or collapsed
    corners) the closed form stops being the projection; there both vectors
    rotate by length-weighted shares keeping their lengths. Corners with
    parallel edges (zero area) have no plane and are left as they are.

    ``planar``: angles are signed about +z (x, y components only), so a
    flipped corner has a negative angle and is rotated back.
    With ``return_residual`` also returns |U0 - P0|^2 + |U1 - P1|^2 ((k,)).
    """
    dot = np.einsum("ij,ij->j", U0, U1)
    L0 = np.einsum("ij,ij->j", U0, U0)
    L1 = np.einsum("ij,ij->j", U1, U1)
    sn = U0[0] * U1[1] - U0[1] * U1[0] if planar else None
    a00, a01, a10, a11, r2 = corner_coefficients(L0, L1, dot, sn, cos0, sin0)
    P0 = a00 * U0
    P0 += a01 * U1
    P1 = a11 * U1
    P1 += a10 * U0
    if return_residual:
        return P0, P1, r2
    return P0, P1


def corner_coefficients(L0, L1, dot, sn, cos0, sin0):
    """Scalar core of :func:`project_corners`.

    From |U0|^2, |U1|^2, U0.U1 and the signed sine term ``sn`` (|U0 x U1|,
    or its z component in the plane; None: unsigned, computed here) returns
    the coefficients with P0 = a00 U0 + a01 U1 and P1 = a10 U0 + a11 U1,
    and the residual |U0 - P0|^2 + |U1 - P1|^2, all (k,).
    """
    if sn is None:
        sn = np.sqrt(np.maximum(L0 * L1 - dot * dot, 0.0))
    r = np.sqrt(L0 * L1)
    ok = np.abs(sn) > 1e-9 * r
    if not ok.all():
        r = np.where(ok, r, 1.0)
        sn = np.where(ok, sn, 1.0)
    inv_r = 1.0 / r
    # exp(i delta) = exp(i theta0) exp(-i theta)
    cd = (cos0 * dot + sin0 * sn) * inv_r
    sd = (sin0 * dot - cos0 * sn) * inv_r
    wr = L0 + L1 * (cd * cd - sd * sd)
    wi = L1 * 2.0 * cd * sd
    wn = np.sqrt(wr * wr + wi * wi)
    wn[wn == 0] = 1.0
    ca0 = np.sqrt(np.maximum(0.5 * (1.0 + wr / wn), 0.0))
    sa0 = 0.5 * (wi / wn) / np.where(ca0 > 0, ca0, 1.0)
    k0 = ca0.copy()
    far = cd < 0
    any_far = bool(far.any())
    if any_far:
        delta = np.arctan2(sd[far], cd[far])
        a0 = delta * L1[far] / np.maximum(L0[far] + L1[far], 1e-300)
        ca0[far], sa0[far], k0[far] = np.cos(a0), np.sin(a0), 1.0
    ca1 = cd * ca0 + sd * sa0
    sa1 = sd * ca0 - cd * sa0
    k1 = np.where(far, 1.0, ca1) if any_far else ca1
    # In the corner's plane, n x U0 = (L0 U1 - dot U0) / sn and n x U1 = (dot U1 - L1 U0) / sn.
    inv_sn = 1.0 / sn
    cot = dot * inv_sn
    a00 = k0 * (ca0 + sa0 * cot)
    a01 = -k0 * sa0 * L0 * inv_sn
    a11 = k1 * (ca1 + sa1 * cot)
    a10 = -k1 * sa1 * L1 * inv_sn
    # |U - P|^2 = L sin^2 a for the projection, 2 L (1 - cos a) for a pure rotation.
    r2 = L0 * sa0 * sa0 + L1 * sa1 * sa1
    if any_far:
        r2[far] = 2.0 * (L0[far] * (1.0 - ca0[far]) + L1[far] * (1.0 - ca1[far]))
    if not ok.all():
        a00[~ok], a01[~ok], a11[~ok], a10[~ok], r2[~ok] = 1.0, 0.0, 1.0, 0.0, 0.0
    return a00, a01, a10, a11, r2
