"""The free-direction layout: each triangle chooses the direction it is printed along.

A printed sheet shrinks by ``sigma`` along its path direction ``d`` and keeps its length
across it. The map from the target surface to the flat sheet must therefore, on every
triangle, be an isometry across ``d`` and a stretch by ``1/(1 - sigma)`` along it, with
``sigma`` in ``[s_min, s_max]``: its 2x2 Jacobian has singular values ``1`` and
``lambda`` in ``[1/(1 - s_min), 1/(1 - s_max)]``. The paper's method is the special case
with ``d`` fixed to the isolines, which can only shorten isolines (domes); a free ``d``
also forms saddles and valleys, where the sheet must lose length down the slope.

Local/global iterations (as ARAP): the local step projects every triangle's Jacobian
onto that set in closed form from its 2x2 singular value decomposition; the global step
is one sparse solve with a matrix factored once. The start is the field seen from
above (its vertical projection), which every height field has.
"""

import hashlib
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from pipeline.geometry import quarter_turn
from pipeline.linalg import factor_spd
from pipeline.mechanics.anderson import Anderson

# A Jacobian that leaves the admissible set by more than this (relative) counts as invalid.
INVALID_TOL = 0.01
# Below this shrink a triangle prints the same sheet along any direction.
FREE_BELOW = 0.05
# Global systems kept for the next solve on the same target: a plan lays one target out
# up to three times (the layout, then relaid twice for the stack's shrink), and the fit's
# last probe is the plan's own mesh.
SYSTEMS_KEPT = 2
# Local/global stops where its residual falls by less than this fraction over the last
# STALL_WINDOW iterations: from there on the layout only creeps along soft modes. In plain
# steps the 175 mm dome's layout stalled after 40 of its 200 iterations, its relaid layouts
# after 26 and 11 of 60; laid so, its sheet lay within 0.007 mm of the capped one's and
# settled within 0.002 mm of it (flatten 2.9 -> 1.7 s CPU, simulate 8.6 -> 5.6 s). Mixed
# (:data:`ANDERSON`), a 60 mm dome's stalls after 20 solves, 0.007 mm from the layout 200
# plain steps give. A saddle's residual keeps falling: it runs to the cap.
STALL = 0.005
STALL_WINDOW = 5
# The free layout's local/global steps mixed by Anderson acceleration over the last so
# many (Peng et al. 2018, "Anderson acceleration for geometry optimization and physics
# simulation"): plain steps creep along the layout's soft modes, the mixed ones move
# along them. On the 175 mm coast tile's plan mesh 50 mixed steps rest closer (residual
# 3.43e-4) than 200 plain ones (3.72e-4), in 0.39 s against 0.71 s. 0: plain steps.
ANDERSON = 5
_systems = OrderedDict()
_systems_lock = threading.Lock()  # plans may run in threads side by side


@dataclass
class FreeLayout:
    """Outcome of :func:`flatten_free`.

    xy : (n, 2) mm, the flat sheet; direction : (m, 2) unit print direction of each
    triangle in the layout; sigma : (m,) its shrink (clamped to the printable range);
    iterations, residual, converged : the solve's (converged: it stopped before its cap);
    flipped : triangles turned over in the layout; across_strain : how far the layout
    stretches each triangle across ``d``, where it must keep its length ({mean_abs,
    max_abs}; the isoline method's ``bridge_strain``);
    invalid_area_fraction, stretch_area_fraction, overshrink_area_fraction : shares of the
    sheet whose map leaves the admissible set by more than 1 %, and why.
    """

    xy: np.ndarray
    direction: np.ndarray
    sigma: np.ndarray
    iterations: int
    residual: float
    flipped: int
    invalid_area_fraction: float
    stretch_area_fraction: float
    overshrink_area_fraction: float
    invalid_edge_fraction: float = 0.0
    timing_s: dict = field(default_factory=dict)
    converged: bool = False
    across_strain: dict = field(default_factory=dict)

    @property
    def overlapping(self):
        return self.flipped > 0

    def report(self):
        """The ``flatten`` section of the report for this method."""
        s = self.sigma
        # The isoline method's keys too, where they mean the same, so that a tool reading
        # one method's report reads the other's; the layout is planar from the start.
        return {"method": "free", "iterations": int(self.iterations),
                "converged": bool(self.converged), "overlapping": bool(self.overlapping),
                "max_abs_z_mm": 0.0, "bridge_strain": dict(self.across_strain),
                "stretch_area_fraction": float(self.stretch_area_fraction),
                "overshrink_area_fraction": float(self.overshrink_area_fraction),
                "residual": float(self.residual), "flipped_triangles": int(self.flipped),
                "invalid_area_fraction": float(self.invalid_area_fraction),
                "invalid_area": {"would_stretch": float(self.stretch_area_fraction),
                                 "would_shrink_too_much": float(self.overshrink_area_fraction)},
                "invalid_edge_fraction": float(self.invalid_edge_fraction),
                "sigma": {"min": float(s.min()), "p05": float(np.percentile(s, 5)),
                          "mean": float(s.mean()), "p95": float(np.percentile(s, 95)),
                          "max": float(s.max())}}


def target_frames(vertices, faces):
    """Each target triangle in an orthonormal frame of its own plane.

    Returns (Dm_inv (m, 2, 2), area (m,) mm^2): the inverse of the matrix whose columns
    are the sides corner 0 -> 1 and 0 -> 2 in that frame.
    """
    P = np.asarray(vertices, dtype=float)[faces]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    l1 = np.maximum(np.linalg.norm(e1, axis=1), 1e-12)
    u = e1 / l1[:, None]
    n = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(n, axis=1)
    v = np.cross(n, u)
    v /= np.maximum(np.linalg.norm(v, axis=1), 1e-12)[:, None]
    Dm = np.zeros((len(P), 2, 2))
    Dm[:, 0, 0] = l1
    Dm[:, 0, 1] = np.einsum("fi,fi->f", e2, u)
    Dm[:, 1, 1] = np.maximum(np.einsum("fi,fi->f", e2, v), 1e-9 * l1)
    return np.linalg.inv(Dm), area


def svd2(J):
    """Signed SVD of 2x2 matrices: J = U diag(s1, s2) V^T with U, V rotations and
    s1 >= |s2| (s2 < 0 for a reflection). J : (m, 2, 2). Returns U, s (m, 2), V."""
    phi, s, theta = _svd2_angles(J)
    return _rot(phi), s, _rot(-theta)


def _svd2_angles(J):
    """:func:`svd2` as the angles of its rotations: (phi (m,), s (m, 2), theta (m,)),
    U = rot(phi), V = rot(-theta)."""
    a, b, c, d = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
    E, F = (a + d) / 2, (a - d) / 2
    G, H = (c + b) / 2, (c - b) / 2
    Q, R = np.hypot(E, H), np.hypot(F, G)
    a1, a2 = np.arctan2(G, F), np.arctan2(H, E)
    return (a2 + a1) / 2, np.stack([Q + R, Q - R], axis=1), (a2 - a1) / 2


def _rot(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([c, -s], axis=1), np.stack([s, c], axis=1)], axis=1)


def project(J, lam_lo, lam_hi):
    """The nearest admissible Jacobians: singular values ``lambda`` in [lam_lo, lam_hi]
    and 1, no reflection. J : (m, 2, 2). Returns (P (m, 2, 2), lambda (m,), U (m, 2, 2)).

    With ``lambda >= 1`` the larger singular value becomes ``lambda`` (clamped) and the
    smaller one 1; the singular vectors stay, which is the nearest point of the set
    (von Neumann's trace inequality)."""
    phi, s, theta = _svd2_angles(J)
    lam = np.clip(s[:, 0], lam_lo, lam_hi)
    # U diag(lam, 1) V^T written out: the batched 2x2 products cost three times more.
    cp, sp_, ct, st = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    P = np.empty_like(J)
    P[:, 0, 0] = lam * cp * ct - sp_ * st
    P[:, 0, 1] = -lam * cp * st - sp_ * ct
    P[:, 1, 0] = lam * sp_ * ct + cp * st
    P[:, 1, 1] = cp * ct - lam * sp_ * st
    U = np.empty_like(J)
    U[:, 0, 0], U[:, 0, 1], U[:, 1, 0], U[:, 1, 1] = cp, -sp_, sp_, cp
    return P, lam, U


def projected(J, lam_lo, lam_hi):
    """:func:`project`'s ``P`` alone ((m, 2, 2)), without the trigonometry: a 2x2 matrix
    is a similarity (its conformal part, norm ``Q``) plus a reflection-similarity (its
    anticonformal part, norm ``R``), with singular values ``Q + R`` and ``Q - R`` and
    the singular vectors set by the parts' angles. The nearest admissible matrix keeps
    the angles and makes the norms ``(lambda + 1) / 2`` and ``(lambda - 1) / 2``; a
    part of norm 0 takes angle 0, as :func:`_svd2_angles` does. Two and a half times
    faster than ``project``, the local step of every iteration."""
    a, b, c, d = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
    E, F = (a + d) / 2, (a - d) / 2
    G, H = (c + b) / 2, (c - b) / 2
    # Not np.hypot: its guard against overflow costs as much as forty products, and
    # Jacobian entries are O(1).
    Q, R = np.sqrt(E * E + H * H), np.sqrt(F * F + G * G)
    lam = np.clip(Q + R, lam_lo, lam_hi)
    qs = (lam + 1) / (2 * np.maximum(Q, 1e-300))
    rs = (lam - 1) / (2 * np.maximum(R, 1e-300))
    E *= qs
    H *= qs
    F *= rs
    G *= rs
    # A part of norm 0 has angle 0 (rare: only exact similarities or reflections).
    for norm, cos, sin, size in ((Q, E, H, (lam + 1) / 2), (R, F, G, (lam - 1) / 2)):
        zero = norm == 0
        if zero.any():
            cos[zero], sin[zero] = size[zero], 0.0
    P = np.empty_like(J)
    P[:, 0, 0], P[:, 1, 1] = E + F, E - F
    P[:, 0, 1], P[:, 1, 0] = G - H, G + H
    return P


def violation(J, lam_lo, lam_hi, tol=INVALID_TOL):
    """Which triangles' Jacobians leave the set by more than ``tol``: (stretch, overshrink)
    bool arrays. Stretch: some direction would have to get longer than printed (the
    smaller singular value under 1, or a flip); overshrink: more shrink than the material
    gives, or shrink in two directions."""
    _, s, _ = svd2(J)
    stretch = (s[:, 1] < 1 - tol) | (s[:, 0] < lam_lo * (1 - tol))
    over = ~stretch & ((s[:, 0] > lam_hi * (1 + tol)) | (s[:, 1] > 1 + tol))
    return stretch, over


def flatten_free(mesh, s_min=0.0, s_max=0.34, iterations=50, tol=1e-6, start_xy=None,
                 smooth_free_below=FREE_BELOW):
    """Lay the target ``mesh`` flat with a free print direction per triangle.

    Parameters
    ----------
    mesh : Mesh (vertices (n, 3) mm, faces (m, 3) counter-clockwise from above)
    s_min, s_max : the printable shrink range
    iterations : cap of local/global solves (mixed by :data:`ANDERSON`)
    tol : stop when the largest vertex move of an iteration is below ``tol`` times the
        mean edge length
    start_xy : (n, 2) mm, optional start (default: the vertical projection)
    smooth_free_below : where sigma is below this the direction is free; it is
        smoothed from the neighbours so the tool paths turn gently there

    Returns
    -------
    FreeLayout
    """
    t0 = time.perf_counter()
    V = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    m = len(faces)
    lam_lo, lam_hi = 1.0 / (1.0 - s_min), 1.0 / (1.0 - s_max)
    system = global_system(V, faces)
    G, area = system[0], system[4]
    X = (np.asarray(start_xy, dtype=float) if start_xy is not None else V[:, :2]).copy()
    setup = time.perf_counter() - t0
    X, it, residual, converged = local_global(
        system, X, lambda J: projected(J, lam_lo, lam_hi), iterations, tol, ANDERSON)
    J = jacobians(G, X, m)
    _, lam, U = project(J, lam_lo, lam_hi)
    d = U[:, :, 0]
    sigma = 1.0 - 1.0 / lam
    d = smooth_free_directions(d, sigma, faces, smooth_free_below)
    stretch, over = violation(J, lam_lo, lam_hi)
    total = area.sum()
    flipped = int(np.count_nonzero(np.linalg.det(J) <= 0))
    return FreeLayout(xy=X, direction=d, sigma=sigma, iterations=it, residual=residual,
                      flipped=flipped, converged=converged, across_strain=_across_strain(J, d),
                      invalid_area_fraction=float(area[stretch | over].sum() / total),
                      stretch_area_fraction=float(area[stretch].sum() / total),
                      overshrink_area_fraction=float(area[over].sum() / total),
                      invalid_edge_fraction=_invalid_edges_along(J, d, X, faces, lam_lo, lam_hi),
                      timing_s={"setup": setup, "total": time.perf_counter() - t0})


def global_system(V, faces):
    """The global step of a local/global layout of the target ``V`` ((n, 3) mm),
    ``faces`` ((m, 3)): G stacking each triangle's Jacobian (target frame -> layout) as
    two rows of ``G X``, G^T W (W the target areas), the factored G^T W G (plus ``eps``
    times the identity, which pins the free translation), ``eps``, the areas (m,).
    The layout whose Jacobians come nearest the wanted ``P`` ((m, 2, 2)) in the
    area-weighted sense is then ``lu.solve(GtW @ P^T stacked + eps X)``.
    The last :data:`SYSTEMS_KEPT` systems are kept by their target's contents: the same
    target again is not factored again. Callers must not change what they get."""
    V = np.ascontiguousarray(V, dtype=float)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    key = (V.shape, faces.shape, hashlib.blake2b(V.tobytes(), digest_size=16).digest(),
           hashlib.blake2b(faces.tobytes(), digest_size=16).digest())
    with _systems_lock:
        system = _systems.get(key)
        if system is not None:
            _systems.move_to_end(key)
            return system
    system = _global_system(V, faces)
    with _systems_lock:
        _systems[key] = system
        while len(_systems) > SYSTEMS_KEPT:
            _systems.popitem(last=False)
    return system


def forget_systems():
    """Drop the kept global systems (their factors are tens of MB on a large sheet): for
    when no more layouts of the same target will be solved, e.g. once a plan's sheet is
    laid out and settled."""
    with _systems_lock:
        _systems.clear()


def _global_system(V, faces):
    n, m = len(V), len(faces)
    Dm_inv, area = target_frames(V, faces)
    base = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
    C = np.einsum("kc,fcd->fkd", base, Dm_inv)               # J = sum_k x_k (x) C[f, k]
    rows = np.broadcast_to(np.arange(2 * m).reshape(m, 1, 2), (m, 3, 2))
    cols = np.broadcast_to(faces[:, :, None], (m, 3, 2))
    G = sp.csr_matrix((C.ravel(), (rows.ravel(), cols.ravel())), shape=(2 * m, n))
    W = sp.diags(np.repeat(area, 2))
    GtW = (G.T @ W).tocsr()
    M = (GtW @ G).tocsc()
    eps = 1e-8 * float(M.diagonal().mean())
    lu = factor_spd(M + eps * sp.identity(n, format="csc"))
    return G, GtW, lu, eps, area


def local_global(system, X, project_jacobians, iterations, tol, window=0):
    """Local/global iterations from the layout ``X`` ((n, 2) mm): each triangle's Jacobian
    ``J`` projected onto what it may be (``project_jacobians(J)`` -> (m, 2, 2)), then the
    layout whose Jacobians come nearest those (``system`` of :func:`global_system`),
    until the largest vertex move is below ``tol`` mean edge lengths, the residual has
    fallen by less than :data:`STALL` over the last :data:`STALL_WINDOW` iterations, or
    ``iterations`` solves. With ``window`` the steps are mixed by Anderson acceleration
    over the last ``window`` (:class:`pipeline.mechanics.anderson.Anderson`); a mixed
    point whose residual is above the last one's is dropped for the plain step from it.
    Returns (X, iterations, the area-weighted residual of the last projection, converged).
    """
    G, GtW, lu, eps, area = system
    m = len(area)
    mean_edge = float(np.sqrt(area.mean() * 4 / np.sqrt(3)))

    def step(X):
        J = jacobians(G, X, m)
        P = project_jacobians(J)
        residual = float(np.sqrt(np.einsum("f,fij,fij->", area, J - P, J - P) / area.sum()))
        # G X stacks each triangle's J as two rows (columns of J^T): rhs = G^T W P^T.
        rhs = GtW @ np.transpose(P, (0, 2, 1)).reshape(2 * m, 2)
        Xn = lu.solve(rhs + eps * X)
        return residual, Xn - Xn.mean(axis=0) + X.mean(axis=0)

    mix = Anderson(window) if window else None
    it, residual, converged, history = 0, np.inf, False, []
    plain = X
    while it < iterations:
        it += 1
        residual, Xn = step(X)
        if mix is not None and history and residual > history[-1]:
            # The plain step from the last point kept, already at hand.
            residual, X = history[-1], plain
            if it == iterations:
                break
            it += 1
            mix.restart()
            residual, Xn = step(X)
        history.append(residual)
        move = float(np.abs(Xn - X).max())
        plain = Xn
        if move < tol * mean_edge or _stalled(history):
            converged = True
            break
        X = Xn if mix is None else mix.mixed(X, Xn)
    return plain, it, residual, converged


def _stalled(history):
    """Whether the residuals ``history`` fell by less than :data:`STALL` of the last one
    over the last :data:`STALL_WINDOW` iterations."""
    if len(history) <= STALL_WINDOW:
        return False
    return history[-1 - STALL_WINDOW] - history[-1] < STALL * history[-1]


def _across_strain(J, d):
    """Strain of the layout across each triangle's print direction ``d`` ((m, 2) unit),
    from the Jacobians ``J`` ((m, 2, 2), target -> layout): {mean_abs, max_abs}."""
    across = quarter_turn(d)
    target = np.linalg.solve(J, across[:, :, None])[:, :, 0]
    strain = 1.0 / np.maximum(np.linalg.norm(target, axis=1), 1e-12) - 1.0
    return {"mean_abs": float(np.abs(strain).mean()) if len(strain) else 0.0,
            "max_abs": float(np.abs(strain).max()) if len(strain) else 0.0}


def jacobians(G, X, m):
    """(m, 2, 2) Jacobians of the layout ``X`` ((n, 2)) from the stacked rows ``G``."""
    return np.transpose((G @ X).reshape(m, 2, 2), (0, 2, 1))


def smooth_free_directions(d, sigma, faces, below, anchor=10.0, prefer=None, strength=None):
    """Make the print direction smooth where the sheet leaves it free.

    Where ``sigma`` is small the layout barely stretches and any direction prints the
    same sheet; left as the solver found it, it turns on rounding noise and the stripes
    fork there. One sparse solve over the triangles' neighbour graph (as a line field:
    doubled angles) keeps each direction where ``sigma >= below`` and lets the others
    follow their neighbours: minimises sum over neighbours |z_f - z_g|^2 + sum over
    triangles w_f |z_f - z0_f|^2, w_f = anchor * min(sigma_f / below, 1)^2.
    With ``prefer`` ((m, 2) unit) the free triangles also lean toward it, by
    ``anchor * (1 - min(sigma_f / below, 1))^2 * strength_f`` (``strength`` (m,) in
    0..1): the direction the curvature program wants (:mod:`pipeline.layout.curvature`).
    d : (m, 2) unit; returns (m, 2).
    """
    from pipeline.mechanics.constraints import topology
    m = len(d)
    free = 1.0 - np.clip(np.asarray(sigma, dtype=float) / below, 0.0, 1.0)
    w = anchor * (1.0 - free) ** 2
    u = np.zeros(m) if prefer is None else anchor * free ** 2 * np.asarray(strength, float)
    if np.all(w >= anchor) or not np.any(w + u > 0):
        return d
    top = topology(faces)
    f0, f1 = top.hinge_faces.T
    adj = sp.coo_matrix((np.ones(len(f0)), (f0, f1)), shape=(m, m))
    adj = (adj + adj.T).tocsr()
    L = sp.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj
    rhs = w * _doubled(d)
    if prefer is not None:
        rhs = rhs + u * _doubled(prefer)
    # A graph Laplacian and a positive diagonal: with the default ordering and pivoting
    # it took twice the fill and half as long again (the 175 mm coast tile's fine mesh:
    # 1.16 against 0.58 million entries, 55 against 38 ms).
    lu = factor_spd(L + sp.diags(w + u + 1e-9))
    z = lu.solve(rhs.real) + 1j * lu.solve(rhs.imag)
    ang = np.angle(z) / 2
    return np.stack([np.cos(ang), np.sin(ang)], axis=1)


def _doubled(d):
    """A line field as unit complex numbers of doubled angle: (m,) complex."""
    return np.exp(2j * np.arctan2(d[:, 1], d[:, 0]))


def _invalid_edges_along(J, d, X, faces, lam_lo, lam_hi, tol=INVALID_TOL):
    """Share of triangles whose side most along ``d`` needs a shrink outside the range
    (the paper's invalid-edge figure, on the edges that print)."""
    P = X[faces]
    sides = P[:, [1, 2, 0]] - P
    along = np.abs(np.einsum("fkc,fc->fk", sides, d)) / np.maximum(
        np.linalg.norm(sides, axis=2), 1e-12)
    k = np.argmax(along, axis=1)
    e = sides[np.arange(len(faces)), k]                     # flat side
    Jinv = np.linalg.inv(J)
    t = np.einsum("fij,fj->fi", Jinv, e)                    # its length on the target
    ratio = np.linalg.norm(e, axis=1) / np.maximum(np.linalg.norm(t, axis=1), 1e-12)
    bad = (ratio < lam_lo * (1 - tol)) | (ratio > lam_hi * (1 + tol))
    return float(bad.mean())
