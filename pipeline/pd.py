"""Projective dynamics (local/global, as in ShapeOp) for triangle sheets.

Shared machinery of :mod:`pipeline.flatten` and :mod:`pipeline.simulate`:
the mesh topology (edges, hinges, corners), the constraints of paper 6.2.1 as
rows of one sparse matrix with vectorised projections, and a solver that
factors the global system once.

Energy, with per-row weights ``w`` (linear in the paper's weights)::

    E(x) = 1/2 sum_r w_r |(A x)_r - p_r(A x)|^2

Row scalings follow ShapeOp so the paper's weights keep their balance:
an edge row is ``(x_j - x_i) / sqrt(l0)`` (energy ``w (l - t)^2 / l0``, mm),
a hinge row is ``sqrt(3 / (A0 + A1)) K0`` (Wardetzky et al. isometric
bending, dimensionless), a shear corner is two rows ``x_k / sqrt(L_k)``.
ShapeOp squares its weights (they multiply the rows); here they multiply the
energy, which is what "sum_i w_i A_i^T A_i" in the issue means.
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

# Faces x 3 per block of the local step: big enough to amortise numpy's call
# overhead, small enough for its temporaries to stay in cache.
_BLOCK = 3 * 4096


def _next_in_face(k, _cache={}):
    """Index of half-edge j+1 of the same face, for k consecutive half-edges."""
    if k not in _cache:
        j = np.arange(k)
        _cache[k] = (j // 3) * 3 + (j % 3 + 1) % 3
    return _cache[k]


# Rest triangles are kept at least this fat (area / sum of squared sides) so
# that inconsistent rest lengths (a bridge strained past the triangle
# inequality) give bounded cotangents instead of an ill-conditioned system.
_MIN_FATNESS = 1e-4


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
    """
    area, cot, _ = face_geometry(top, edge_len)
    f0, f1 = top.hinge_faces[:, 0], top.hinge_faces[:, 1]
    v0, v1 = top.hinges[:, 0], top.hinges[:, 1]
    c0_f0 = _corner_value(top.faces, cot, f0, v0)
    c1_f0 = _corner_value(top.faces, cot, f0, v1)
    c0_f1 = _corner_value(top.faces, cot, f1, v0)
    c1_f1 = _corner_value(top.faces, cot, f1, v1)
    k = np.stack([c1_f0 + c1_f1, c0_f0 + c0_f1, -(c0_f0 + c1_f0), -(c0_f1 + c1_f1)], axis=1)
    return k * np.sqrt(3.0 / (area[f0] + area[f1]))[:, None]


def _corner_value(faces, values, f, v):
    """``values[f, k]`` where ``faces[f, k] == v`` (vectorised)."""
    k = np.argmax(faces[f] == v[:, None], axis=1)
    return values[f, k]


@dataclass
class EdgeTargets:
    """Per-edge strain constraint: length within [lo, hi] mm, energy weight, rest length.

    ``rest`` only scales the row (ShapeOp's 1/sqrt(l0)); lo == hi is a fixed length.
    """

    lo: np.ndarray
    hi: np.ndarray
    weight: np.ndarray
    rest: np.ndarray


class PDSystem:
    """Constraint rows, projections and a once-factored global solve.

    Every constraint row here is a scaled half-edge vector, so the solver
    works on half-edge vectors ``H = D x`` ((d, 3m): half-edge k of face f
    runs from corner k to corner k+1): edge rows pick one half-edge per edge,
    shear rows are the two half-edges at a corner, and the right-hand side is
    ``D^T Q`` with per-half-edge sums ``Q``. That is one sparse product each
    way per iteration instead of one per constraint row.

    Positions are component-major ``(d, n)`` (d = 3, or 2 in the plane), so
    every projection runs on contiguous 1-D arrays.

    Parameters
    ----------
    top : Topology
    edge : EdgeTargets
        One entry per edge of ``top.edges``.
    rest_len : (e,) float, mm
        Rest edge lengths that define hinge cotangents, corner rest angles
        and the shear rows' scaling.
    w_bending, w_shear : float
    closeness : float
        Proximal weight relative to the mean diagonal of the system; removes
        the translation null space and damps the solve.
    """

    def __init__(self, top, edge, rest_len, w_bending=0.025, w_shear=0.25, closeness=1e-6):
        self.top = top
        n, faces = top.n, top.faces
        m, e = len(faces), len(top.edges)
        self.n_edges, self.n_corners = e, 3 * m
        a = faces.ravel()
        b = faces[:, [1, 2, 0]].ravel()
        he = np.arange(3 * m)
        self.D = sp.csr_matrix((np.concatenate([np.ones(3 * m), -np.ones(3 * m)]),
                                (np.concatenate([he, he]), np.concatenate([b, a]))), shape=(3 * m, n))
        self.DT = self.D.T.tocsr()
        # One half-edge per edge, and whether it runs like the sorted edge (lo -> hi).
        he_edge = top.face_edge[:, [2, 0, 1]].ravel()  # half-edge k is opposite corner k+2
        first = np.full(e, -1)
        first[he_edge[::-1]] = he[::-1]
        self.edge_he = first
        self.edge_sign = np.where(a[first] == top.edges[:, 0], 1.0, -1.0)
        self.edge_scale = 1.0 / np.sqrt(edge.rest)
        self.edge_coef = self.edge_sign * self.edge_scale
        self.edge_lo = edge.lo * self.edge_scale
        self.edge_hi = edge.hi * self.edge_scale
        self.edge_w = np.asarray(edge.weight, dtype=float)
        ei = np.arange(e)
        self.Ae = sp.csr_matrix((np.concatenate([-self.edge_scale, self.edge_scale]),
                                 (np.concatenate([ei, ei]), top.edges.T.ravel())), shape=(e, n))
        self.AeT = self.Ae.T.tocsr()
        # Shear rows: corner k has U0 = s_k h_k and U1 = -s_{k+2} h_{k+2}, s = 1/sqrt(rest length).
        self.he_scale = 1.0 / np.sqrt(rest_len[he_edge])
        corner = np.arange(3 * m).reshape(m, 3)
        self.he_scale_next2 = self.he_scale[corner[:, [2, 0, 1]].ravel()]
        self.w_shear = float(w_shear)
        _, _, angle = face_geometry(top, rest_len)
        self.theta0 = angle.ravel()
        self.cos0, self.sin0 = np.cos(self.theta0), np.sin(self.theta0)
        h = len(top.hinges)
        K = hinge_weights(top, rest_len)
        self.B = sp.csr_matrix((K.ravel(), (np.repeat(np.arange(h), 4), top.hinges.ravel())),
                               shape=(h, n))
        self.w_bending = float(w_bending)
        q = 2.0 * self.w_shear * self.he_scale ** 2
        np.add.at(q, self.edge_he, self.edge_w * self.edge_scale ** 2)
        M = (self.DT @ sp.diags(q) @ self.D + self.w_bending * (self.B.T @ self.B)).tocsc()
        self.eps = closeness * float(M.diagonal().mean())
        M = M + self.eps * sp.identity(n, format="csc")
        self.lu = splu(M, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})

    @property
    def A(self):
        """The stacked projection rows (edges, then corners' U0, then U1) as one
        sparse matrix ((e + 6m, n)); built on demand, for checks and tests."""
        m3 = self.n_corners
        E = sp.csr_matrix((self.edge_coef, (np.arange(self.n_edges), self.edge_he)),
                          shape=(self.n_edges, m3))
        s = self.he_scale
        U0 = sp.diags(s)
        roll = (np.arange(m3) // 3) * 3 + (np.arange(m3) % 3 + 2) % 3
        U1 = sp.csr_matrix((-s[roll], (np.arange(m3), roll)), shape=(m3, m3))
        return (sp.vstack([E, U0, U1]) @ self.D).tocsr()

    def half_edges(self, Xc):
        """Half-edge vectors of positions ``Xc`` ((d, n) mm): (d, 3m)."""
        return np.stack([self.D @ x for x in Xc])

    def project(self, Xc, planar=False):
        """Local step at ``Xc`` ((d, n)).

        Returns (Q, energy): Q is a pair (shear projections weighted and
        summed per half-edge (d, 3m), weighted edge projections (d, e)); the
        global step's right-hand side is ``D^T Q[0] + Ae^T Q[1]``. Energy is
        the total constraint energy at ``Xc``.
        ``planar`` measures corner angles signed about +z so that flipped
        triangles in the plane are pushed back instead of ignored.
        """
        d, m = len(Xc), len(self.top.faces)
        H = self.half_edges(Xc)
        Ye = np.stack([self.Ae @ x for x in Xc])
        Pe, re2 = project_edges(Ye, self.edge_lo, self.edge_hi, return_residual=True)
        Pe *= self.edge_w
        Q = np.empty_like(H)
        rc2 = 0.0
        # Blocks of faces keep the corner arithmetic in cache on big meshes.
        for lo in range(0, 3 * m, _BLOCK):
            sl = slice(lo, min(lo + _BLOCK, 3 * m))
            rc2 += self._corner_block(H[:, sl], Q[:, sl], sl, planar)
        bend = sum(float(np.dot(v, v)) for v in (self.B @ x for x in Xc))
        E = 0.5 * (float(self.edge_w @ re2) + self.w_shear * rc2 + self.w_bending * bend)
        return (Q, Pe), E

    def _corner_block(self, H, Q, sl, planar):
        """Shear projections of the corners of a block of whole faces.

        H : (d, 3b) half-edge vectors of the block; Q : (d, 3b) output,
        overwritten with the weighted projections summed per half-edge.
        Returns the block's summed squared residual.
        """
        d, k = H.shape
        b = k // 3
        # Corner k of a face: U0 = s_k h_k, U1 = -s_{k+2} h_{k+2}; work on
        # scalars per corner and on H and Hn (= h_{k+2}) only.
        Hn = H.reshape(d, b, 3)[:, :, [2, 0, 1]].reshape(d, k)
        s0 = self.he_scale[sl]
        s1 = self.he_scale_next2[sl]
        hh = np.einsum("ij,ij->j", H, H)
        L0 = hh * s0 * s0
        L1 = hh.reshape(b, 3)[:, [2, 0, 1]].ravel() * (s1 * s1)
        ss = -s0 * s1
        dot = np.einsum("ij,ij->j", H, Hn) * ss
        sn = (H[0] * Hn[1] - H[1] * Hn[0]) * ss if planar else None
        a00, a01, a10, a11, rc2 = corner_coefficients(L0, L1, dot, sn, self.cos0[sl],
                                                      self.sin0[sl])
        # Half-edge j is U0 of corner j and -U1 of corner j+1; with
        # h_{j+1} = -h_j - h_{j+2} (a triangle closes) the weighted sum is
        # Q_j = w s_j [(a00_j s_j + a11_{j+1} s_j + a10_{j+1} s_{j+1}) h_j
        #              + (a10_{j+1} s_{j+1} - a01_j s_{j+2}) h_{j+2}].
        nxt = _next_in_face(k)
        a10n = a10[nxt] * s0[nxt]
        ws = self.w_shear * s0
        alpha = (a00 * s0 + a11[nxt] * s0 + a10n) * ws
        beta = (a10n - a01 * s1) * ws
        np.multiply(H, alpha, out=Q)
        Hn *= beta
        Q += Hn
        return float(rc2.sum())

    def energy(self, Xc, planar=False):
        """Total constraint energy at ``Xc`` ((d, n) mm)."""
        return self.project(Xc, planar)[1]

    def energy_terms(self, Xc, planar=False):
        """Energy per constraint kind: dict edge/shear/bending (for diagnostics).

        Evaluated through the explicit rows :attr:`A` and the vector
        projections, independently of the fused :meth:`project`.
        """
        Y = np.stack([self.A @ x for x in Xc])
        e, c = self.n_edges, self.n_corners
        _, re2 = project_edges(Y[:, :e], self.edge_lo, self.edge_hi, return_residual=True)
        P0, P1 = project_corners(Y[:, e:e + c], Y[:, e + c:], self.cos0, self.sin0, planar)
        rc = np.concatenate([Y[:, e:e + c] - P0, Y[:, e + c:] - P1], axis=1)
        bend = sum(float(np.dot(v, v)) for v in (self.B @ x for x in Xc))
        return {"edge": 0.5 * float(self.edge_w @ re2),
                "shear": 0.5 * self.w_shear * float(np.einsum("ij,ij->", rc, rc)),
                "bending": 0.5 * self.w_bending * bend}

    def solve(self, Q, Xc):
        """Global step: argmin_x sum_r w_r |A_r x - p_r|^2 + w_b |B x|^2 + eps |x - X|^2.

        Q : pair from :meth:`project`; Xc : (d, n). Returns (d, n).
        """
        Qs, Pe = Q
        rhs = np.stack([self.DT @ q + self.AeT @ p for q, p in zip(Qs, Pe)])
        rhs += self.eps * Xc
        # (d, n) C-order is (n, d) Fortran order, which SuperLU takes without a copy.
        return np.ascontiguousarray(self.lu.solve(rhs.T).T)

    def step(self, Xc, planar=False):
        """One local/global iteration on ``Xc`` ((d, n)); returns (new Xc, energy before)."""
        Q, E = self.project(Xc, planar)
        return self.solve(Q, Xc), E


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


def minimize(system, X, iterations, tol, planar=False, anderson=5, callback=None, start=0):
    """Run PD iterations to equilibrium, with safeguarded Anderson acceleration.

    Anderson acceleration (type II, window ``anderson``) extrapolates the PD
    fixed-point map from the last few steps; a candidate is kept only if it
    lowers the energy, otherwise the plain PD step is taken and the history
    restarts (Peng et al. 2018, "Anderson acceleration for geometry
    optimization and physics simulation"). PD alone converges slowly on the
    soft, low-frequency modes of a thin sheet (buckling, global bending).

    Parameters
    ----------
    system : PDSystem
    X : (d, n) float, mm
        Start positions (component-major).
    iterations : int
    tol : float, mm
        Stop when the largest vertex move of an iteration is below this.
    anderson : int
        History length; 0 gives plain PD.
    callback : callable(iteration, (n, d) positions), optional
    start : int
        Iteration number offset for the callback.

    Returns
    -------
    X : (d, n), energies : list of float (energy at the start of each
    iteration), iterations run, converged : bool
    """
    Q, E = system.project(X, planar)
    energies = []
    dF, dG = [], []
    f_prev = g_prev = None
    converged = False
    it = 0
    for it in range(1, iterations + 1):
        energies.append(E)
        G = system.solve(Q, X)
        F = (G - X).ravel()
        cand = G
        if anderson:
            g = G.ravel()
            if f_prev is not None:
                dF.append(F - f_prev)
                dG.append(g - g_prev)
                if len(dF) > anderson:
                    dF.pop(0)
                    dG.pop(0)
            f_prev, g_prev = F, g
            if dF:
                A = np.stack(dF, axis=1)
                gamma = np.linalg.lstsq(A, F, rcond=None)[0]
                cand = (g - np.stack(dG, axis=1) @ gamma).reshape(G.shape)
        Qc, Ec = system.project(cand, planar)
        if cand is not G and not Ec <= E:
            cand = G
            Qc, Ec = system.project(G, planar)
            dF.clear()
            dG.clear()
            f_prev, g_prev = F, G.ravel()
        change = float(np.abs(cand - X).max())
        X, Q, E = cand, Qc, Ec
        if callback is not None:
            callback(start + it, X.T)
        if change < tol:
            converged = True
            break
    return X, energies, it, converged
