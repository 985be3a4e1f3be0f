"""Forward simulation: does the flat layout rise into the target? (paper 6.2.4)

The flat sheet is given the lengths it will have after the hot-water bath:
every printing edge ``(1 - sigma) * l_flat``, every bridge edge its flat
length. Corner rest angles and hinge cotangents come from those lengths
(law of cosines), so the constraints agree with each other; bending pulls
toward flat as in :mod:`pipeline.flatten`. No relocations. The sheet starts
flat with an upward bump (the bath pushes it one way; see ``pop`` for why
its height matters) and projective dynamics
(Anderson-accelerated) runs to equilibrium with the same once-factored
solver; the result is rigidly aligned to the target (Kabsch, identity
correspondence).

Where the mesh carries a coarser sheet (``Mesh.sheet``: the same cells with
isoline arcs cut to ~2 mm instead of ``l_u``), the sheet is simulated at that
resolution: a coarse isoline edge gets the summed target length of the
printing edges it replaces, scaled to its chord; a coarse diagonal, which
crosses several fine triangles, gets the length the strip it spans has once
shrunk along its isolines only; every dropped vertex follows its arc between
the two kept vertices either side. The displacement is measured on every
vertex of the mesh. On the reference shapes this sheet has 5-7 times fewer
vertices, and the forward simulation is 5-8 times faster; its figures are a
different discretisation's and differ from the full mesh's by up to about
0.5 % of the diameter (``tests/test_simulate.py``).
"""

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from pipeline.flatten import DEFAULT_WEIGHTS, _printing_mask
from pipeline.geometry import edge_index, edge_lengths
from pipeline.constraints import topology
from pipeline.pd import EdgeTargets, PDSystem, minimize


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
    converged : bool
        Largest vertex move per iteration fell below ``tol``.
    mirrored : bool
        The sheet settled upside down relative to the target, and its mirror
        image (z -> -z), which the mirrored start reaches, was kept.
    clamped_edges : int
        Printing edges whose sigma was clamped to the printable range.
    sheet_vertices : int
        Vertices of the sheet that was simulated (fewer than the mesh's on a
        coarse sheet).
    energy_history : list of float
    timing_s : dict
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
    energy_history: list = field(default_factory=list)
    timing_s: dict = field(default_factory=dict)

    def report(self):
        """The ``simulation`` section of ``NAME.report.json``."""
        return {"mean_displacement_mm": float(self.mean_displacement_mm),
                "max_displacement_mm": float(self.max_displacement_mm),
                "iterations": int(self.iterations), "converged": bool(self.converged),
                "mirrored": bool(self.mirrored), "sheet_vertices": int(self.sheet_vertices)}


def simulate(mesh, flat, iterations=300, weights=None, tol=1e-4, s_min=None, s_max=None,
             pop=0.15, anderson=5, callback=None, coarse=True):
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
        Maximum PD iterations. Check ``converged``: on lobed shapes the
        sheet keeps settling slowly, and a shape cut short of equilibrium
        is usually closer to the target than the equilibrium.
    weights : dict, optional
        Overrides of the constraint weights (bridge, printing, bending, shear).
    tol : float
        Stop when the largest vertex move per iteration is below ``tol``
        times the mean rest edge length.
    s_min, s_max : float, optional
        Clamp sigma to what the printer can make (default: no clamping).
    pop : float
        Initial bump height as a fraction of the layout's diameter:
        ``z = pop * diameter * d / d_max`` with d the distance to the boundary.
        PD is slow to leave the nearly flat, buckling state; a bump of the
        order of a part's height (0.15) reaches the same equilibrium on a
        cap in a third of the iterations a small one (0.05) needs.
        A sheet whose parts can bend without stretching (the starfish's
        arms) has several equilibria, and the start picks one: the 167 mm
        starfish of the tests ends 3.2 % of its diameter from the target
        from a bump of 0.05, 0.85 % from 0.15 and 0.43 % from 0.25. On its
        coarse sheet the lowest-energy equilibria found are the far ones.
    anderson : int
        Anderson acceleration window (0: plain PD), see :func:`pipeline.pd.minimize`.
    callback : callable(iteration, (k, 3) positions of the simulated sheet), optional
    coarse : bool
        Simulate the mesh's coarse sheet where it has one (else every vertex).

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
    sheet = mesh.sheet if coarse else None
    if sheet is None:
        kept, faces = np.arange(len(V)), mesh.faces
    else:
        kept, remap = _compact(sheet.faces, len(V))
        faces = remap[sheet.faces]
        pe = _coarse_edges(sheet, pe, len(V))
        pe = remap[pe]
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
    X = np.zeros((3, len(kept)))
    X[:2] = xy[kept].T
    X[2] = pop_profile(xy[kept], top, pop)
    scale = float(rest.mean())
    t1 = time.perf_counter()

    X, energy, it, converged = minimize(system, X, iterations, tol * scale,
                                        anderson=anderson, callback=callback)
    t2 = time.perf_counter()

    P = np.empty_like(V)
    P[kept] = X.T
    if sheet is not None and len(sheet.dropped):
        a, b = sheet.between[:, 0], sheet.between[:, 1]
        P[sheet.dropped] = (1.0 - sheet.t)[:, None] * P[a] + sheet.t[:, None] * P[b]
    aligned, disp = align(P, V)
    # Every constraint is invariant under z -> -z, so the mirrored start
    # settles into the mirror image of this shape: compare it without a second solve.
    aligned_m, disp_m = align(P * np.array([1.0, 1.0, -1.0]), V)
    mirrored = bool(disp_m.mean() < disp.mean())
    if mirrored:
        aligned, disp = aligned_m, disp_m
    return SimResult(vertices=aligned, displacement_mm=disp,
                     mean_displacement_mm=float(disp.mean()),
                     max_displacement_mm=float(disp.max()), iterations=it,
                     converged=converged, mirrored=mirrored, clamped_edges=clamped,
                     sheet_vertices=len(kept),
                     energy_history=energy,
                     timing_s={"setup": t1 - t0, "iterate": t2 - t1,
                               "total": time.perf_counter() - t0})


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
