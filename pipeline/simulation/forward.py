"""Forward simulation: does the flat layout rise into the target? (paper 6.2.4)

The flat sheet is given the lengths it will have after the hot-water bath:
every printing edge ``(1 - sigma) * l_flat``, every bridge edge its flat
length. Corner rest angles and hinge cotangents come from those lengths
(law of cosines), so the constraints agree with each other; bending pulls
toward flat as in :mod:`pipeline.layout.isoline`. No relocations. The sheet starts
flat with an upward bump (the bath pushes it one way; see ``pop`` for why
its height matters) and settles to rest under L-BFGS on the constraint
energy, preconditioned with the once-factored PD matrix
(:func:`pipeline.mechanics.pd.minimize_lbfgs`); the result is rigidly aligned to the target (Kabsch, identity
correspondence).

Where the mesh carries a coarser sheet (``Mesh.sheet``: the same cells with
isoline arcs cut to ~2 mm instead of ``l_u``), that sheet settles first: a
coarse isoline edge gets the summed target length of the printing edges it
replaces, scaled to its chord; a coarse diagonal, which crosses several fine
triangles, gets the length the strip it spans has once shrunk along its
isolines only; every dropped vertex follows its arc between the two kept
vertices either side. The full mesh then settles from that shape, so the
figures are the full mesh's. Both stages run until the sheet is at rest over
ten iterations (``rest_tol``), not until one step is small: a thin sheet
creeps along its soft modes in steps far below any sensible per-step
tolerance. The coarse sheet has 5-7 times fewer vertices and takes most of
that creep cheaply; from the bump alone the full mesh of a 175 mm dome is
still creeping after 400 iterations.
"""

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from pipeline.layout.isoline import DEFAULT_WEIGHTS, _printing_mask
from pipeline.geometry import edge_index, edge_lengths
from pipeline.mechanics.constraints import topology
from pipeline.mechanics.pd import EdgeTargets, PDSystem, minimize_lbfgs


@dataclass
class SimResult:
    """Outcome of :func:`simulate`.

    Attributes
    ----------
    vertices : (n, 3) float, mm
        Equilibrium shape, rigidly aligned to the target vertices.
    displacement_mm : (n,) float
        Distance of each aligned vertex from its target position.
    mean_displacement_mm, max_displacement_mm : float
    iterations : int
        Of both stages together.
    converged : bool
        The last stage came to rest (``rest_tol``) before its iteration cap.
    mirrored : bool
        The sheet settled upside down relative to the target, and its mirror
        image (z -> -z), which the mirrored start reaches, was kept.
    clamped_edges : int
        Printing edges whose sigma was clamped to the printable range.
    sheet_vertices : int
        Vertices of the sheet the figures come from (fewer than the mesh's
        only with ``refine=False``).
    coarse_iterations : int
        Iterations of the coarse sheet's stage (0 without one).
    full_iterations : int or None
        Iterations on the plan's own mesh; None: ``iterations`` after the coarse stage's.
        The free method's settle counts its coarse trials apart and ``iterations`` are
        only the plan's mesh's (:func:`pipeline.simulation.staged.simulate_free`).
    energy_history : list of float
        Both stages' energies, one list (each stage starts its own).
    timing_s : dict
        Seconds: ``coarse``, ``full`` (the stages run) and ``total``.
    faces, target : (m, 3) int and (n, 3) mm, the sheet's own triangles and target
        where it was simulated on another mesh than the plan's (else None)
    """

    vertices: np.ndarray
    displacement_mm: np.ndarray
    mean_displacement_mm: float
    max_displacement_mm: float
    iterations: int
    converged: bool
    mirrored: bool
    clamped_edges: int
    sheet_vertices: int = 0
    coarse_iterations: int = 0
    full_iterations: int = None
    energy_history: list = field(default_factory=list)
    timing_s: dict = field(default_factory=dict)
    faces: np.ndarray = None
    target: np.ndarray = None

    def report(self):
        """The ``simulation`` section of ``NAME.report.json``."""
        return {"mean_displacement_mm": float(self.mean_displacement_mm),
                "max_displacement_mm": float(self.max_displacement_mm),
                "iterations": int(self.iterations), "converged": bool(self.converged),
                "mirrored": bool(self.mirrored), "sheet_vertices": int(self.sheet_vertices),
                "coarse_iterations": int(self.coarse_iterations),
                "full_iterations": int(self.iterations - self.coarse_iterations
                                       if self.full_iterations is None
                                       else self.full_iterations)}


def simulate(mesh, flat, iterations=300, weights=None, s_min=None, s_max=None,
             pop=0.15, callback=None, coarse=True, refine=True, rest_tol=2e-5):
    """Let the flat layout shrink and settle; compare with the target.

    Parameters
    ----------
    mesh : Mesh
        The target (its vertices are the reference; its faces and edge classes
        are the sheet's).
    flat : FlatResult or (n, 2) float
        The layout (``xy``, mm) and, for a FlatResult, its ``sigma``.
        Plain arrays need ``sigma`` from the layout: it is recomputed.
    iterations : int
        Maximum iterations per stage (coarse sheet, full mesh). Check
        ``converged``: shapes with parts that bend without stretching (the
        starfish's arms, the elongated peak's skirt) are still moving after
        300 + 300, and move further from the target as they go.
    weights : dict, optional
        Overrides of the constraint weights (bridge, printing, bending, shear).
    rest_tol : float
        At rest when the sheet moved less than this times the layout's
        diameter (root mean square over its vertices) in the last ten
        iterations (see :func:`pipeline.mechanics.pd.minimize_lbfgs`): 3.5 um on a
        175 mm part.
    s_min, s_max : float, optional
        Clamp sigma to what the printer can make (default: no clamping).
    pop : float
        Initial bump height as a fraction of the layout's diameter:
        ``z = pop * diameter * d / d_max`` with d the distance to the boundary.
        The solver is slow to leave the nearly flat, buckling state; a bump
        of the order of a part's height (0.15) gets out of it quickly.
    callback : callable(iteration, (k, 3) positions of the simulated sheet), optional
    coarse : bool
        Where the mesh has a coarse sheet, settle that first.
    refine : bool
        Then settle the full mesh from the coarse sheet's shape (else the
        figures are the coarse sheet's).

    Returns
    -------
    SimResult
    """
    t0 = time.perf_counter()
    w = dict(DEFAULT_WEIGHTS)
    if weights:
        w.update(weights)
    V = np.asarray(mesh.vertices, dtype=float)
    xy = np.asarray(getattr(flat, "xy", flat), dtype=float)
    pe = np.asarray(mesh.printing_edges, dtype=np.int64).reshape(-1, 2)
    l_print = edge_lengths(xy, pe)
    sigma = 1.0 - edge_lengths(V, pe) / l_print
    lo = -np.inf if s_min is None else s_min
    hi = np.inf if s_max is None else s_max
    clamped = int(np.count_nonzero((sigma < lo) | (sigma > hi)))
    target = (1.0 - np.clip(sigma, lo, hi)) * l_print
    diameter = float(np.linalg.norm(xy.max(axis=0) - xy.min(axis=0)))
    settle = dict(iterations=iterations, rest_tol=rest_tol * diameter, callback=callback)
    sheet = mesh.sheet if coarse else None
    P, it, converged, energy, n_sim = None, 0, False, [], len(V)
    timing = {}
    if sheet is not None:
        t = time.perf_counter()
        P, it, converged, energy, n_sim = _settle(mesh, xy, pe, target, l_print, w, sheet,
                                                  pop=pop, **settle)
        timing["coarse"] = time.perf_counter() - t
    coarse_it = it
    if sheet is None or refine:
        t = time.perf_counter()
        P, it_f, converged, e_f, n_sim = _settle(mesh, xy, pe, target, l_print, w, None,
                                                 pop=pop, start=P, **settle)
        it, energy = it + it_f, energy + e_f
        timing["full"] = time.perf_counter() - t

    aligned, disp = align(P, V)
    # Every constraint is invariant under z -> -z, so the mirrored start
    # settles into the mirror image of this shape: compare it without a second solve.
    aligned_m, disp_m = align(P * np.array([1.0, 1.0, -1.0]), V)
    mirrored = bool(disp_m.mean() < disp.mean())
    if mirrored:
        aligned, disp = aligned_m, disp_m
    timing["total"] = time.perf_counter() - t0
    return SimResult(vertices=aligned, displacement_mm=disp,
                     mean_displacement_mm=float(disp.mean()),
                     max_displacement_mm=float(disp.max()), iterations=it,
                     converged=converged, mirrored=mirrored, clamped_edges=clamped,
                     sheet_vertices=n_sim, coarse_iterations=coarse_it,
                     energy_history=energy, timing_s=timing)


def _settle(mesh, xy, pe, target, l_print, w, sheet, pop, start=None, **settle):
    """Settle the shrunk sheet: the full mesh (``sheet`` None) or a coarse sheet.

    ``pe`` ((p, 2) int) are the mesh's printing edges, ``target`` and ``l_print``
    ((p,) mm) their shrunk and flat lengths. The sheet starts flat with the ``pop`` bump, or at ``start``
    ((n, 3) mm, every mesh vertex). Returns (positions (n, 3) of every mesh
    vertex, iterations, converged, energies, vertices simulated).
    """
    V = mesh.vertices
    if sheet is None:
        kept, faces = np.arange(len(V)), mesh.faces
    else:
        kept, remap = _compact(sheet.faces, len(V))
        faces = remap[sheet.faces]
        pe = remap[_coarse_edges(sheet, pe, len(V))]
    top = topology(faces, len(kept))
    is_print, row = _printing_mask(top.edges, pe)
    rest = edge_lengths(xy[kept], top.edges)
    # A coarse isoline edge shrinks like the printing edges it stands for.
    shrunk = np.bincount(row, target, len(rest)) / np.maximum(np.bincount(row, l_print, len(rest)),
                                                              1e-12)
    rest[is_print] *= shrunk[is_print]
    if sheet is not None:
        # A coarse diagonal crosses several fine triangles: the strip it spans shrinks
        # along the isolines only, so its length follows that anisotropic shrink.
        # The mesh's printing and bridge edges are all its edges.
        fine = np.concatenate([mesh.printing_edges, mesh.bridge_edges])
        new = ~is_print & (edge_index(fine, kept[top.edges]) < 0)
        G = _shrink_metric(xy, mesh.printing_edges, target / l_print, len(V))
        a, b = kept[top.edges[new, 0]], kept[top.edges[new, 1]]
        d = xy[b] - xy[a]
        Gm = 0.5 * (G[a] + G[b])
        rest[new] = np.sqrt(np.einsum("ki,kij,kj->k", d, Gm, d))
    edge_w = np.where(is_print, w["printing"], w["bridge"])
    system = PDSystem(top, EdgeTargets(rest, rest, edge_w, rest), rest,
                      w_bending=w["bending"], w_shear=w["shear"])
    if start is None:
        X = np.zeros((3, len(kept)))
        X[:2] = xy[kept].T
        X[2] = pop_profile(xy[kept], top, pop)
    else:
        X = np.ascontiguousarray(np.asarray(start, dtype=float)[kept].T)
    X, energy, it, converged = minimize_lbfgs(system, X, **settle)
    P = np.empty_like(V)
    P[kept] = X.T
    if sheet is not None and len(sheet.dropped):
        a, b = sheet.between[:, 0], sheet.between[:, 1]
        P[sheet.dropped] = (1.0 - sheet.t)[:, None] * P[a] + sheet.t[:, None] * P[b]
    return P, it, converged, energy, len(kept)


def _compact(faces, n):
    """Vertices used by ``faces`` ((k,) int) and the map from mesh ids to 0..k-1 ((n,) int)."""
    used = np.zeros(n, bool)
    used[faces.ravel()] = True
    kept = np.flatnonzero(used)
    remap = np.full(n, -1, dtype=np.int64)
    remap[kept] = np.arange(len(kept))
    return kept, remap


def _coarse_edges(sheet, printing_edges, n):
    """The coarse edge ((p, 2) int, mesh ids) each printing edge lies on.

    A printing edge with a dropped end lies on the coarse edge between that
    end's two kept neighbours; one with both ends kept is a coarse edge itself.
    """
    ends = np.full((n, 2), -1, dtype=np.int64)
    ends[sheet.dropped] = sheet.between
    u, v = printing_edges[:, 0], printing_edges[:, 1]
    out = printing_edges.copy()
    from_v = ends[v, 0] >= 0
    out[from_v] = ends[v[from_v]]
    from_u = ends[u, 0] >= 0
    out[from_u] = ends[u[from_u]]
    return out


def _shrink_metric(xy, printing_edges, ratio, n):
    """Per-vertex rest metric of the shrunk sheet: (n, 2, 2), flat mm -> rest mm squared.

    ``G = I - (1 - r^2) t t^T`` averaged (by length) over the printing edges at
    a vertex, with t the edge's flat direction and r its target/flat ratio:
    lengths along the isoline shrink by r, across it they stay.
    Vertices on no printing edge get the identity.
    """
    d = xy[printing_edges[:, 1]] - xy[printing_edges[:, 0]]
    length = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    t = d / length[:, None]
    c = length * (1.0 - ratio ** 2)
    parts = (c * t[:, 0] * t[:, 0], c * t[:, 0] * t[:, 1], c * t[:, 1] * t[:, 1])
    ends = printing_edges.T.ravel()
    w = np.bincount(ends, np.tile(length, 2), n)
    xx, xy_, yy = (np.bincount(ends, np.tile(p, 2), n) / np.maximum(w, 1e-12) for p in parts)
    G = np.zeros((n, 2, 2))
    G[:, 0, 0] = 1.0 - xx
    G[:, 0, 1] = G[:, 1, 0] = -xy_
    G[:, 1, 1] = 1.0 - yy
    return G


def pop_profile(xy, top, pop):
    """Initial bump (n,) mm: ``pop * diameter`` times the normalised distance to the boundary."""
    bnd = top.boundary_vertices
    if len(bnd) == 0 or pop == 0:
        return np.zeros(len(xy))
    d, _ = cKDTree(xy[bnd]).query(xy)
    diameter = float(np.linalg.norm(xy.max(axis=0) - xy.min(axis=0)))
    return pop * diameter * d / max(float(d.max()), 1e-12)


def align(P, T):
    """Rigidly align points ``P`` to ``T`` ((n, 3) each, same order; Kabsch).

    Returns (aligned P (n, 3), per-point distance to T (n,)).
    """
    cp, ct = P.mean(axis=0), T.mean(axis=0)
    H = (P - cp).T @ (T - ct)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    A = (P - cp) @ R.T + ct
    return A, np.linalg.norm(A - T, axis=1)
