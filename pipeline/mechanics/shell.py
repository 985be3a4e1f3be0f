"""A thin shell with units: membrane and bending stiffness from the printed thickness.

The paper's sheet model (:mod:`pipeline.mechanics.pd`) weighs an edge's strain by
``1/l0`` and a hinge's bending by a dimensionless row, so the balance between
stretching and bending moves with the mesh size: the simulated shape measures the
mesh, not the sheet. Here both energies are integrals over the sheet, discretised
so that they converge under refinement (Grinspun et al. 2003, "Discrete shells"):

- membrane, per triangle: ``1/2 * h * A * |F - R|^2``, F the deformation gradient
  from the triangle's rest shape to its 3-D shape and R the nearest matrix with
  orthonormal columns (the stretch away from rest, ~ ``eps_1^2 + eps_2^2``);
- a barrier against collapse, per triangle: ``ALPHA * h * A * (J - 1 - log J)``, J the
  area over the rest area: zero at rest, growing without bound as a triangle collapses
  (the stretch term alone lets a triangle flatten to a line at a finite cost, and a
  collapsed triangle has no normal for the bending term to turn);
- bending, per interior edge: ``1/2 * (h^3 / 12) * 3 |e|^2 / (A_0 + A_1) *
  (theta - theta_rest)^2``, theta the signed dihedral angle (0 flat).

With Young's modulus 1 and Poisson's ratio 0 (the modulus cancels from the rest
shape; the printed sheet's ratio is unknown and matters little against the
factor h^2 / 12 = 0.19 mm^2 between the two for a 1.5 mm sheet). ``theta_rest``
is the curvature a bilayer programs: 0 for equal layers.

:class:`ShellSystem` has the interface :func:`pipeline.mechanics.pd.minimize_lbfgs`
uses (``project``, ``gradient``, ``precondition``): the energy and its exact
gradient, and as preconditioner the quadratic form of both energies at rest,
factored once.
"""

import numpy as np
import scipy.sparse as sp

from pipeline.linalg import factor_spd
from pipeline.mechanics.constraints import _MIN_HINGE_ANGLE_DEG, topology

# A triangle's rest shape is kept at least this fat (height over longest side),
# so a sliver of the mesh gives a bounded, not an infinite, deformation gradient.
_MIN_REST_HEIGHT = 1e-3
# Rest areas in the bending weight are kept above this fraction of the median.
_MIN_AREA_FRACTION = 0.05
# Weight of the collapse barrier relative to the stretch term: small, so that it
# changes nothing while triangles keep their area to a few per cent.
ALPHA = 0.1
# Triangles or hinges per block of the energy. Whole-mesh temporaries (a megabyte
# each on a 30k-triangle sheet) went back to the kernel when freed and page-faulted
# on every call: more system time than the arithmetic. A block's (3, block) floats
# (192 kB) are reused by malloc and stay in cache; smaller blocks pay numpy's call
# overhead more often (4096 measured 10% slower, 1024 twice as slow).
_BLOCK = 8192


def rest_frames(rest_len):
    """Rest triangles from their side lengths, in a frame of their own.

    rest_len : (m, 3) float, mm, the side opposite each corner.
    Returns (Dm_inv (m, 2, 2), area (m,) mm^2): the inverse of the matrix whose
    columns are the rest sides corner 0 -> 1 and corner 0 -> 2.
    """
    a, b, c = (np.asarray(rest_len, dtype=float)[:, k] for k in range(3))
    x = (b * b + c * c - a * a) / (2.0 * c)
    longest = np.maximum(np.maximum(a, b), c)
    y = np.maximum(np.sqrt(np.maximum(b * b - x * x, 0.0)), _MIN_REST_HEIGHT * longest)
    det = c * y
    inv = np.empty((len(a), 2, 2))
    # Dm = [[c, x], [0, y]].
    inv[:, 0, 0] = 1.0 / c
    inv[:, 0, 1] = -x / det
    inv[:, 1, 0] = 0.0
    inv[:, 1, 1] = 1.0 / y
    return inv, 0.5 * det


def min_angle_deg(rest_len):
    """Smallest corner angle of each rest triangle: (m,) degrees."""
    l2 = np.asarray(rest_len, dtype=float) ** 2
    num = l2[:, [1, 2, 0]] + l2[:, [2, 0, 1]] - l2
    den = 2.0 * np.sqrt(l2[:, [1, 2, 0]] * l2[:, [2, 0, 1]])
    return np.degrees(np.arccos(np.clip(num / np.maximum(den, 1e-300), -1.0, 1.0))).min(axis=1)


def face_lengths(vertices, faces):
    """Side lengths of each triangle, opposite each corner: (m, 3) float, mm."""
    P = np.asarray(vertices, dtype=float)[faces]
    return np.linalg.norm(P[:, [2, 0, 1]] - P[:, [1, 2, 0]], axis=2)


class ShellSystem:
    """Energy, gradient and preconditioner of a thin shell over ``faces``.

    Parameters
    ----------
    faces : (m, 3) int
    n : int, vertex count
    rest_len : (m, 3) float, mm
        Each triangle's rest side lengths (opposite corners 0, 1, 2). Neighbours
        may disagree on a shared side (a metric no surface has): the energy
        finds the best compromise.
    thickness_mm : (m,) float
        Printed thickness of each triangle.
    theta_rest : (h,) float, rad, optional
        Rest dihedral angle of each hinge (``topology(faces).hinges``), signed as
        :func:`dihedral`; default 0 (bending toward flat).
    closeness : float
        Weight, relative to the preconditioner's mean diagonal, that removes its
        translation null space.
    """

    def __init__(self, faces, n, rest_len, thickness_mm, theta_rest=None, closeness=1e-6):
        self.top = top = topology(faces, n)
        self.faces = top.faces
        m = len(self.faces)
        h = np.broadcast_to(np.asarray(thickness_mm, dtype=float), (m,))
        self._rest_len = np.asarray(rest_len, dtype=float)
        self.Dm_inv, self.rest_area = rest_frames(rest_len)
        self.w_face = h * self.rest_area
        # Corner coefficients: F = sum_k x_k C[f, k, :].
        base = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
        self.C = np.einsum("kc,fcd->fkd", base, self.Dm_inv)
        # The nonzero entries of Dm_inv (its [1, 0] is 0): F = [x1 - x0, x2 - x0] Dm_inv.
        self._inv = [np.ascontiguousarray(self.Dm_inv[:, i, j])
                     for i, j in ((0, 0), (0, 1), (1, 1))]
        self.hinges = top.hinges
        self._corners = [np.ascontiguousarray(c) for c in self.faces.T]
        self._hinge_cols = [np.ascontiguousarray(c) for c in top.hinges.T]
        # Where each gradient contribution goes (three per triangle, then four per
        # hinge), as an (n, 3m + 4h) 0/1 matrix: its product gathers each vertex's
        # terms, twice as fast as np.bincount scattering them.
        to = np.concatenate([self.faces.T.ravel(), top.hinges.T.ravel()])
        self._scatter = sp.csr_matrix((np.ones(len(to)), (to, np.arange(len(to)))),
                                      shape=(n, len(to)))
        # The terms themselves, written by the energies into one buffer kept between calls
        # (a fresh one page-faults): this makes :meth:`project` not reentrant.
        self._terms = np.empty((3, len(to)))
        self._membrane_terms = self._terms[:, :3 * m]
        self._bending_terms = self._terms[:, 3 * m:]
        hf = top.hinge_faces
        area = np.maximum(self.rest_area, _MIN_AREA_FRACTION * float(np.median(self.rest_area)))
        self._e_len = e_len = self._hinge_rest_length(rest_len)
        stiffness = 0.5 * (h[hf[:, 0]] ** 3 + h[hf[:, 1]] ** 3) / 12.0
        self.k_hinge = stiffness * 3.0 * e_len ** 2 / (area[hf[:, 0]] + area[hf[:, 1]])
        # A sliver's dihedral angle measures the mesher's rounding, not the sheet's
        # curvature (its normal turns by 1/height per mm of noise): no bending there,
        # as in the paper's model (pipeline.mechanics.constraints).
        sliver = min_angle_deg(rest_len) < _MIN_HINGE_ANGLE_DEG
        self.k_hinge[sliver[hf[:, 0]] | sliver[hf[:, 1]]] = 0.0
        self.hinge_height = 2.0 * (area[hf[:, 0]] + area[hf[:, 1]]) / (3.0 * e_len)
        self.theta_rest = (np.zeros(len(self.hinges)) if theta_rest is None
                           else np.asarray(theta_rest, dtype=float))
        self.lu, self.eps = self._factor(n, closeness)

    def _side(self, rest_len, f, u, v):
        """Rest length of side u-v of faces f ((k,) each): the side opposite the
        corner that is neither u nor v."""
        tri = self.faces[f]
        corner = np.argmax((tri != u[:, None]) & (tri != v[:, None]), axis=1)
        return np.asarray(rest_len, dtype=float)[f, corner]

    def _hinge_rest_length(self, rest_len):
        """Rest length of each hinge's edge: the mean of its two faces' values."""
        hf, (v0, v1) = self.top.hinge_faces, self.hinges[:, :2].T
        return 0.5 * (self._side(rest_len, hf[:, 0], v0, v1)
                      + self._side(rest_len, hf[:, 1], v0, v1))

    def _feet(self, rest_len):
        """Where each hinge's opposite vertices project onto its edge at rest, as
        the fraction of the way from v0 to v1: two (h,)."""
        hf, (v0, v1, v2, v3) = self.top.hinge_faces, self.hinges.T
        e2 = self._e_len ** 2
        out = []
        for f, w in ((hf[:, 0], v2), (hf[:, 1], v3)):
            a2 = self._side(rest_len, f, v0, w) ** 2
            b2 = self._side(rest_len, f, v1, w) ** 2
            out.append((a2 + e2 - b2) / (2.0 * e2))
        return out

    def _factor(self, n, closeness):
        """The preconditioner: membrane and bending quadratic forms at rest."""
        m = len(self.faces)
        rows = np.broadcast_to(np.arange(2 * m).reshape(m, 1, 2), (m, 3, 2))
        cols = np.broadcast_to(self.faces[:, :, None], (m, 3, 2))
        G = sp.csr_matrix((self.C.ravel(), (rows.ravel(), cols.ravel())), shape=(2 * m, n))
        W = sp.diags(np.repeat(self.w_face, 2))
        # Bending near rest: theta ~ (unit hinge normal) . (dtheta/dx) x; a
        # Laplacian-like row (x2 + x3 - x0 - x1 weighted) stands for it.
        hb = self._hinge_rows_at_rest(n, *self._feet(self._rest_len))
        M = (G.T @ W @ G + hb.T @ sp.diags(self.k_hinge) @ hb).tocsc()
        eps = closeness * float(M.diagonal().mean())
        M = M + eps * sp.identity(n, format="csc")
        return factor_spd(M), eps

    def _hinge_rows_at_rest(self, n, t2, t3):
        """(h, n) rows whose value on a nearly flat sheet is the hinge's dihedral
        angle (:func:`dihedral`'s gradient at rest, its normal component)."""
        hi = self.hinges
        # d theta / d (normal offset) of x2 and x3 is 1/height; the edge's ends share
        # it by where x2 and x3 project onto the edge, so rigid motions give 0.
        h0, h1 = self._opposite_heights()
        g2, g3 = 1.0 / h0, 1.0 / h1
        coef = np.stack([-(1 - t2) * g2 - (1 - t3) * g3, -t2 * g2 - t3 * g3, g2, g3], axis=1)
        return sp.csr_matrix((coef.ravel(), (np.repeat(np.arange(len(hi)), 4), hi.ravel())),
                             shape=(len(hi), n))

    def _opposite_heights(self):
        """Rest heights of each hinge's opposite vertices over its edge: two (h,) mm.

        The true ones, slivers included: the energy's dihedral angle turns by
        1/height per mm an opposite vertex moves, and a preconditioner that did
        not know that would send every step far past a sliver's minimum."""
        hf = self.top.hinge_faces
        e_len = self._e_len
        return (np.maximum(2.0 * self.rest_area[hf[:, 0]] / e_len, 1e-9),
                np.maximum(2.0 * self.rest_area[hf[:, 1]] / e_len, 1e-9))

    # ------------------------------------------------------------ energy

    def project(self, X):
        """Energy and gradient at ``X`` ((3, n) mm): (gradient (3, n), energy)."""
        e = self._membrane(X, self._membrane_terms) + self._bending(X, self._bending_terms)
        g = np.empty_like(X)
        for i in range(3):
            g[i] = self._scatter @ self._terms[i]
        return g, e

    def gradient(self, g, X):
        """The gradient :meth:`project` computed at ``X``."""
        return g

    def precondition(self, G):
        """The preconditioner (plus closeness) solved for ``G`` ((3, n)): (3, n)."""
        return np.ascontiguousarray(self.lu.solve(np.ascontiguousarray(G).T).T)

    def energy_terms(self, X):
        """Membrane and bending energy at ``X`` ((3, n)): dict, N mm with E = 1 N/mm^2."""
        return {"membrane": self._membrane(X, self._membrane_terms),
                "bending": self._bending(X, self._bending_terms)}

    def _membrane(self, X, out):
        """Membrane and barrier energy at ``X`` ((3, n) mm); writes each corner's
        gradient to ``out`` ((3, 3m), corner-major as ``faces.T``)."""
        m = len(self.faces)
        e = 0.0
        for sl in _blocks(m):
            G = [out[:, k * m + sl.start:k * m + sl.stop] for k in range(3)]
            e += self._membrane_block(X, sl, *G)
        return e

    def _membrane_block(self, X, sl, g0, g1, g2):
        """:meth:`_membrane` on the faces ``sl``: energy, gradients into g0..g2 ((3, k))."""
        # Component arrays throughout: F[d] is the (3, k) column d of every F.
        # np.take gathers columns four times faster than X[:, index].
        c0, c1, c2 = (np.take(X, c[sl], axis=1) for c in self._corners)
        e1, e2 = np.subtract(c1, c0, out=c1), np.subtract(c2, c0, out=c2)
        i00, i01, i11 = (c[sl] for c in self._inv)
        F0, F1 = e1 * i00, e1 * i01 + e2 * i11
        R0, R1 = nearest_orthonormal((F0, F1))
        D0, D1 = np.subtract(F0, R0, out=F0), np.subtract(F1, R1, out=F1)
        w, area = self.w_face[sl], self.rest_area[sl]
        e = 0.5 * float(w @ (_dot(D0, D0) + _dot(D1, D1)))
        D0 *= w
        D1 *= w
        # dE/dx_k = w (F - R) C_k (R is the Euclidean projection: no term of its own).
        N = _cross(e1, e2)          # (3, k), twice the area
        norm = np.maximum(np.sqrt(_dot(N, N)), 1e-300)
        J = norm / (2.0 * area)
        wa = ALPHA * w
        e += float(wa @ (J - 1.0 - np.log(J)))
        # d|N|/dx_k = unit(N) x (x_{k+2} - x_{k+1}); the corners' terms sum to zero.
        N *= wa * (1.0 - 1.0 / J) / (2.0 * area) / norm
        np.subtract(D0 * i00 + D1 * i01, _cross(N, e2), out=g1)
        np.add(D1 * i11, _cross(N, e1), out=g2)
        np.add(g1, g2, out=g0)
        np.negative(g0, out=g0)
        return e

    def _bending(self, X, out):
        """Bending energy at ``X`` ((3, n) mm); writes each hinge vertex's gradient
        to ``out`` ((3, 4h), vertex-major as ``hinges.T``)."""
        h = len(self.hinges)
        e = 0.0
        for sl in _blocks(h):
            theta, grads = _dihedral_components(X, [c[sl] for c in self._hinge_cols], True)
            r = theta - self.theta_rest[sl]
            kr = self.k_hinge[sl] * r
            e += 0.5 * float(kr @ r)
            for k, gk in enumerate(grads):
                np.multiply(gk, kr, out=out[:, k * h + sl.start:k * h + sl.stop])
        return e


def _blocks(count):
    """Slices of at most :data:`_BLOCK` covering ``range(count)``."""
    return [slice(i, min(i + _BLOCK, count)) for i in range(0, count, _BLOCK)]


def nearest_orthonormal(F):
    """The nearest matrices with orthonormal columns: ``F (F^T F)^(-1/2)``.

    F : pair of (3, m) arrays, the two columns of m (3, 2) matrices; returns the
    same. Closed form for the 2x2 square root; a collapsed triangle (rank < 2)
    gets a regularised one.
    """
    f0, f1 = F
    a = (f0 * f0).sum(axis=0)
    b = (f0 * f1).sum(axis=0)
    c = (f1 * f1).sum(axis=0)
    tiny = 1e-12 * np.maximum(a + c, 1e-300)
    a, c = a + tiny, c + tiny
    s = np.sqrt(np.maximum(a * c - b * b, 0.0))
    t = np.sqrt(a + c + 2.0 * s)
    # sqrt(M) = (M + sqrt(det M) I) / t for a 2x2 SPD M; invert that 2x2.
    p, q, r = (a + s) / t, b / t, (c + s) / t
    det = np.maximum(p * r - q * q, 1e-300)
    i00, i01, i11 = r / det, -q / det, p / det
    return f0 * i00 + f1 * i01, f0 * i01 + f1 * i11


def dihedral(V, hinges, with_gradient=False):
    """Signed dihedral angle of each hinge: (h,) rad, 0 for a flat pair.

    V : (n, 3) mm; hinges : (h, 4) int as :attr:`Topology.hinges` (edge v0 -> v1
    in the face of v2, v1 -> v0 in the face of v3). Positive where the pair folds
    away from the normal of its faces (a ridge seen from that side: a dome whose
    faces face up); negative for a valley (the inside of a bowl).
    With ``with_gradient``, also (h, 4, 3): d theta / d position of v0..v3.
    """
    out = _dihedral_components(np.asarray(V, dtype=float).T, np.asarray(hinges).T,
                               with_gradient)
    if not with_gradient:
        return out
    theta, grads = out
    return theta, np.stack([gk.T for gk in grads], axis=1)


def _dihedral_components(X, hinges, with_gradient=False):
    """:func:`dihedral` on (3, n) positions, ``hinges`` as its four (h,) vertex
    columns, gradients as four (3, h) arrays (one per hinge vertex): component rows
    keep every product a contiguous pass (four times faster than (h, 3) rows and
    ``np.cross``)."""
    x0, x1, x2, x3 = (np.take(X, c, axis=1) for c in hinges)
    e = np.subtract(x1, x0, out=x1)
    a = np.subtract(x2, x0, out=x2)
    b = np.subtract(x3, x0, out=x3)
    n0 = _cross(e, a)
    n1 = _cross(b, e)
    el = np.maximum(np.sqrt(_dot(e, e)), 1e-300)
    theta = np.arctan2(_dot(_cross(n0, n1, out=x0), e) / el, _dot(n0, n1))
    if not with_gradient:
        return theta
    # Moving an opposite vertex along its face normal by its height turns the face
    # by one radian; the edge's ends share the opposite vertices' pull by where
    # those project onto the edge, so rigid motions leave theta unchanged.
    g2 = np.multiply(n0, -el / np.maximum(_dot(n0, n0), 1e-300), out=n0)
    g3 = np.multiply(n1, -el / np.maximum(_dot(n1, n1), 1e-300), out=n1)
    el2 = el * el
    t2 = _dot(a, e) / el2
    t3 = _dot(b, e) / el2
    g0 = np.add(g2 * (t2 - 1.0), g3 * (t3 - 1.0), out=a)
    g1 = np.add(g0, g2, out=b)
    g1 += g3
    np.negative(g1, out=g1)
    return theta, (g0, g1, g2, g3)


def _cross(a, b, out=None):
    """Cross products of (3, k) component arrays: (3, k) (``out`` if given, which
    must not be ``a`` or ``b``)."""
    c = np.empty_like(a) if out is None else out
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.multiply(a[j], b[k], out=c[i])
        c[i] -= a[k] * b[j]
    return c


def _dot(a, b):
    """Dot products of (3, k) component arrays: (k,)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
