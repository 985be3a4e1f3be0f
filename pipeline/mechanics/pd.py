"""Projective dynamics (local/global, as in ShapeOp) for triangle sheets.

Shared machinery of :mod:`pipeline.layout.isoline` and :mod:`pipeline.simulation.forward`:
the constraints of paper 6.2.1 (projections in :mod:`pipeline.mechanics.constraints`)
as rows of one sparse system, a fused vectorised local step, a global step
that is factored once, and Anderson-accelerated iteration to equilibrium.

Energy, with per-row weights ``w`` (linear in the paper's weights)::

    E(x) = 1/2 sum_r w_r |(A x)_r - p_r(A x)|^2

Row scalings follow ShapeOp so the paper's weights keep their balance:
an edge row is ``(x_j - x_i) / sqrt(l0)`` (energy ``w (l - t)^2 / l0``, mm),
a hinge row is ``sqrt(3 / (A0 + A1)) K0`` (Wardetzky et al. isometric
bending, dimensionless), a shear corner is two rows ``x_k / sqrt(L_k)``.
ShapeOp squares its weights (they multiply the rows); here they multiply the
energy, which is what "sum_i w_i A_i^T A_i" in the paper means. With edges
~1-2 mm long, w_bending / w_edge = 0.025 then behaves like a sheet ~0.6-0.8 mm
thick (bending/stretching stiffness ~ t^2 / 12), close to the printed sheets.
"""

from collections import deque
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import blas

from pipeline.linalg import factor_spd
from pipeline.mechanics.anderson import Anderson
from pipeline.mechanics.constraints import (corner_coefficients, face_geometry, hinge_weights,
                                            project_corners, project_edges, row_lengths)

# Faces x 3 per block of the local step: big enough to amortise numpy's call
# overhead, small enough for its temporaries to stay in cache.
_BLOCK = 3 * 4096


def _next_in_face(k, step=1, _cache={}):
    """Index of half-edge j+step (mod 3) of the same face, for k consecutive half-edges."""
    if (k, step) not in _cache:
        j = np.arange(k)
        _cache[k, step] = (j // 3) * 3 + (j % 3 + step) % 3
    return _cache[k, step]


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
        self.edge_scale = 1.0 / np.sqrt(row_lengths(edge.rest))
        self.edge_coef = self.edge_sign * self.edge_scale
        self.edge_lo = edge.lo * self.edge_scale
        self.edge_hi = edge.hi * self.edge_scale
        self.edge_w = np.asarray(edge.weight, dtype=float)
        ei = np.arange(e)
        self.Ae = sp.csr_matrix((np.concatenate([-self.edge_scale, self.edge_scale]),
                                 (np.concatenate([ei, ei]), top.edges.T.ravel())), shape=(e, n))
        self.AeT = self.Ae.T.tocsr()
        # Shear rows: corner k has U0 = s_k h_k and U1 = -s_{k+2} h_{k+2}, s = 1/sqrt(rest length).
        self.he_scale = 1.0 / np.sqrt(row_lengths(rest_len)[he_edge])
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
        self.M = M.tocsr()
        self.eps = closeness * float(M.diagonal().mean())
        M = M + self.eps * sp.identity(n, format="csc")
        self.lu = factor_spd(M)

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
        m = len(self.top.faces)
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
        # Corner k of a face: U0 = s_k h_k, U1 = -s_{k+2} h_{k+2}; work on
        # scalars per corner and on H and Hn (= h_{k+2}) only. Hn is a flat
        # index gather: ten times faster than permuting a (d, k/3, 3) view.
        prev = _next_in_face(k, 2)
        Hn = np.take(H, prev, axis=1)
        s0 = self.he_scale[sl]
        s1 = self.he_scale_next2[sl]
        hh = np.einsum("ij,ij->j", H, H)
        L0 = hh * s0 * s0
        L1 = hh[prev] * (s1 * s1)
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
        rhs = self._pull(Q)
        rhs += self.eps * Xc
        return self.precondition(rhs)

    def gradient(self, Q, Xc):
        """Gradient of the energy at ``Xc`` ((d, n)) from its projections ``Q``: (d, n).

        The energy is quadratic in x for fixed projections, and a projection's
        distance has the gradient of that quadratic: ``M x - (D^T Q[0] + Ae^T Q[1])``.
        """
        G = np.stack([self.M @ x for x in Xc])
        G -= self._pull(Q)
        return G

    def _pull(self, Q):
        """The projections ``Q`` pulled back onto the vertices: ``D^T Q[0] + Ae^T Q[1]`` ((d, n))."""
        Qs, Pe = Q
        return np.stack([self.DT @ q + self.AeT @ p for q, p in zip(Qs, Pe)])

    def precondition(self, G):
        """The global step's matrix (plus closeness) solved for ``G`` ((d, n)): (d, n)."""
        # (d, n) C-order is (n, d) Fortran order, which SuperLU takes without a copy.
        return np.ascontiguousarray(self.lu.solve(np.ascontiguousarray(G).T).T)

    def step(self, Xc, planar=False):
        """One local/global iteration on ``Xc`` ((d, n)); returns (new Xc, energy before)."""
        Q, E = self.project(Xc, planar)
        return self.solve(Q, Xc), E


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
    mix = Anderson(anderson) if anderson else None
    converged = False
    it = 0
    for it in range(1, iterations + 1):
        energies.append(E)
        G = system.solve(Q, X)
        cand = G if mix is None else mix.mixed(X, G)
        Qc, Ec = system.project(cand, planar)
        if cand is not G and not Ec <= E:
            cand = G
            Qc, Ec = system.project(G, planar)
            mix.restart()
        change = float(np.abs(cand - X).max())
        X, Q, E = cand, Qc, Ec
        if callback is not None:
            callback(start + it, X.T)
        if change < tol:
            converged = True
            break
    return X, energies, it, converged


def minimize_lbfgs(system, X, iterations, rest_tol, window=10, memory=5, callback=None):
    """Minimise the constraint energy by L-BFGS preconditioned with the PD matrix.

    A PD step is a gradient step preconditioned by the global matrix; L-BFGS
    (Liu, Bouaziz and Kavan 2017, "Quasi-Newton methods for real-time
    simulation of hyperelastic materials") starts from that same matrix and
    learns the curvature the local steps miss from the last ``memory`` steps,
    with an Armijo backtracking line search so the energy never rises. On a
    sheet's soft modes (lobes that bend without stretching, a skirt that
    curls) PD and Anderson-accelerated PD creep by steps far below any
    per-step tolerance for hundreds of iterations; this moves along them.

    Parameters
    ----------
    system : PDSystem
    X : (d, n) float, mm
    iterations : int
    rest_tol : float, mm
        At rest when the sheet moved less than this (root mean square over
        its vertices) in the last ``window`` iterations, or when no step
        along the search direction lowers the energy.
    memory : int
        Curvature pairs kept.
    callback : callable(iteration, (n, d) positions), optional

    Returns
    -------
    X : (d, n), energies : list of float (energy at the start of each
    iteration), iterations run, converged : bool
    """
    Q, E = system.project(X)
    g = system.gradient(Q, X)
    S, Y, R = deque(maxlen=memory), deque(maxlen=memory), deque(maxlen=memory)
    past = deque(maxlen=window)
    energies = []
    converged = False
    it = 0
    for it in range(1, iterations + 1):
        energies.append(E)
        past.append(X)
        d = -_two_loop(g, S, Y, system.precondition, R)
        slope = float(np.vdot(g, d))
        if not slope < 0:
            S.clear()
            Y.clear()
            R.clear()
            d = -system.precondition(g)
            slope = float(np.vdot(g, d))
        step = 1.0
        for _ in range(_BACKTRACKS):
            Xn = X + step * d
            Qn, En = system.project(Xn)
            if En <= E + 1e-4 * step * slope:
                break
            step *= 0.5
        else:
            converged = True    # no step lowers the energy: a minimum, to round-off
            break
        gn = system.gradient(Qn, Xn)
        s, y = (Xn - X).ravel(), (gn - g).ravel()
        sy = float(np.dot(s, y))
        if sy > 1e-12 * np.dot(y, y):
            S.append(s)
            Y.append(y)
            R.append(1.0 / sy)
        X, E, g = Xn, En, gn
        if callback is not None:
            callback(it, X.T)
        if _at_rest(past, X, rest_tol):
            converged = True
            break
    return X, energies, it, converged


_BACKTRACKS = 20


def _two_loop(g, S, Y, precondition, R=None):
    """L-BFGS direction: the inverse-Hessian estimate applied to ``g`` ((d, n)).
    ``R``: each pair's ``1 / (y . s)``, kept with the pairs (half the dot products)."""
    q = g.ravel().copy()
    R = [1.0 / np.dot(y, s) for s, y in zip(S, Y)] if R is None else R
    alpha = []
    for s, y, rho in zip(reversed(S), reversed(Y), reversed(R)):
        a = rho * np.dot(s, q)
        alpha.append(a)
        _axpy(y, q, a=-a)
    r = np.ascontiguousarray(precondition(q.reshape(g.shape)), dtype=float).ravel()
    for s, y, rho, a in zip(S, Y, R, reversed(alpha)):
        _axpy(s, r, a=a - rho * np.dot(y, r))
    return r.reshape(g.shape)


def _axpy(x, y, a):
    """``y += a * x`` in place, without the temporary ``a * x``."""
    blas.daxpy(x, y, a=a)


def _at_rest(past, X, rest_tol):
    """``X`` ((d, n)) lies within ``rest_tol`` (RMS, mm) of the oldest of a full ``past``."""
    if len(past) < past.maxlen:
        return False
    d = X - past[0]
    return float(np.sqrt(np.einsum("ij,ij->", d, d) / X.shape[1])) < rest_tol
