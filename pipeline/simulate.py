"""Forward simulation: does the flat layout rise into the target? (paper 6.2.4)

The flat sheet is given the lengths it will have after the hot-water bath:
every printing edge ``(1 - sigma) * l_flat``, every bridge edge its flat
length. Corner rest angles and hinge cotangents come from those lengths
(law of cosines), so the constraints agree with each other; bending pulls
toward flat as in :mod:`pipeline.flatten`. No relocations. The sheet starts
flat with an upward bump (the bath pushes it one way) and projective dynamics
(Anderson-accelerated) runs to equilibrium with the same once-factored
solver; the result is rigidly aligned to the target (Kabsch, identity
correspondence).
"""

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from pipeline.flatten import DEFAULT_WEIGHTS, _printing_mask
from pipeline.geometry import edge_lengths
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
    energy_history: list = field(default_factory=list)
    timing_s: dict = field(default_factory=dict)

    def report(self):
        """The ``simulation`` section of ``NAME.report.json``."""
        return {"mean_displacement_mm": float(self.mean_displacement_mm),
                "max_displacement_mm": float(self.max_displacement_mm),
                "iterations": int(self.iterations), "converged": bool(self.converged),
                "mirrored": bool(self.mirrored)}


def simulate(mesh, flat, iterations=300, weights=None, tol=1e-4, s_min=None, s_max=None,
             pop=0.15, anderson=5, callback=None):
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
    anderson : int
        Anderson acceleration window (0: plain PD), see :func:`pipeline.pd.minimize`.
    callback : callable(iteration, (n, 3) positions), optional

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
    top = topology(mesh.faces, len(V))
    is_print, print_row = _printing_mask(top.edges, mesh.printing_edges)
    l_flat = edge_lengths(xy, top.edges)
    sigma = 1.0 - edge_lengths(V, top.edges)[print_row] / l_flat[print_row]
    lo = -np.inf if s_min is None else s_min
    hi = np.inf if s_max is None else s_max
    clamped = int(np.count_nonzero((sigma < lo) | (sigma > hi)))
    sigma = np.clip(sigma, lo, hi)
    rest = l_flat.copy()
    rest[print_row] = (1.0 - sigma) * l_flat[print_row]
    edge_w = np.where(is_print, w["printing"], w["bridge"])
    system = PDSystem(top, EdgeTargets(rest, rest, edge_w, rest), rest,
                      w_bending=w["bending"], w_shear=w["shear"])
    X = np.zeros((3, len(V)))
    X[:2] = xy.T
    X[2] = pop_profile(xy, top, pop)
    scale = float(rest.mean())
    t1 = time.perf_counter()

    X, energy, it, converged = minimize(system, X, iterations, tol * scale,
                                        anderson=anderson, callback=callback)
    t2 = time.perf_counter()

    P = X.T
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
                     energy_history=energy,
                     timing_s={"setup": t1 - t0, "iterate": t2 - t1,
                               "total": time.perf_counter() - t0})


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
