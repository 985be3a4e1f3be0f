"""Flatten a target mesh into a printable 2-D layout (paper 6.2, 6.2.1-6.2.3).

Each iteration runs one projective-dynamics step (constraints of
:mod:`pipeline.mechanics.pd`: printing strain with the range l0/(1-s_min)..l0/(1-s_max),
bridge strain, cotangent bending toward flat, corner shear) followed by the
paper's three vertex relocations (flattening, stretching, spreading). The
global system is factored once. At the end z is set to 0 and a few purely
in-plane PD iterations make the layout satisfy the constraints in the plane.

Relocations, made dimensionally sound (all displacements in mm):

- flattening: ``dz = -r_k * z``, a fraction of each vertex's height, so the
  push shrinks as the sheet gets flat and never overshoots the plane. The
  paper's ``-z / (z_max sqrt(lx ly))`` has units 1/mm; we keep its intent
  without a size dependence. ``r_k`` ramps the height linearly toward zero
  over 80 % of the iterations, capped at ``w_flattening`` per step (see
  :func:`flattening_rate`): the paper's constant 0.3 from the first step
  crushes summits on fine meshes (measured on the elongated peak at
  l_u = 0.5 mm: 15 % invalid edges against 2.4 % with the ramp).
- stretching: boundary vertices move by ``w_stretching * mean(|e0|, |e1|) *
  N_xy`` (two incident boundary edges; N the area-weighted mean unit normal).
- spreading: for every interior edge and each of its faces f, the vertex of f
  opposite the edge moves by ``w_spreading * mean(|e0|, |e1|) * N_f,xy``
  (e0, e1: the edges of f at that vertex). Contributions are averaged per
  vertex rather than summed so that the push does not grow with valence.
"""

import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import edge_index, edge_lengths, signed_areas_2d
from pipeline.printable import SIGMA_TOL
from pipeline.mechanics.constraints import topology
from pipeline.mechanics.pd import EdgeTargets, PDSystem, minimize

DEFAULT_WEIGHTS = {"bridge": 1.0, "printing": 1.0, "bending": 0.025, "shear": 0.25,
                   "flattening": 0.3, "stretching": 1.0, "spreading": 0.5}


@dataclass
class FlatResult:
    """Outcome of :func:`flatten`.

    Attributes
    ----------
    xy : (n, 2) float, mm
        Flat vertex positions.
    sigma : (p,) float
        Shrink ratio per printing edge (order of ``mesh.printing_edges``):
        ``1 - target_length / flat_length``.
    iterations : int
        Relocation iterations run (the in-plane polish not counted).
    converged : bool
        Relative change per iteration fell below ``tol``.
    max_abs_z_mm : float
        Largest |z| just before the layout was projected onto z = 0.
    flipped_triangles : int
        Faces whose flat orientation opposes the target's.
    boundary_intersections : int
        Pairs of crossing boundary edges in the plane.
    overlapping : bool
        True when the layout folds over itself (flips or boundary crossings;
        for a disk, neither means the layout is an embedding).
    invalid_edge_fraction : float
        Fraction of printing edges with sigma outside [s_min, s_max] by more
        than :data:`SIGMA_TOL`.
    sigma_stats : dict
        ``min, p05, mean, p95, max`` of sigma.
    bridge_strain : dict
        ``mean_abs, max_abs`` of ``l_flat / l0 - 1`` over bridge edges.
    energy_history : list of float
        Total constraint energy at the start of each iteration (relocation
        phase, then in-plane phase).
    timing_s : dict
        ``setup, iterate, planar, total`` in seconds.
    """

    xy: np.ndarray
    sigma: np.ndarray
    iterations: int
    converged: bool
    max_abs_z_mm: float
    flipped_triangles: int
    boundary_intersections: int
    overlapping: bool
    invalid_edge_fraction: float
    sigma_stats: dict
    bridge_strain: dict
    invalid_area_fraction: float = 0.0
    stretch_area_fraction: float = 0.0
    overshrink_area_fraction: float = 0.0
    energy_history: list = field(default_factory=list)
    timing_s: dict = field(default_factory=dict)

    def report(self):
        """The ``flatten`` section of ``NAME.report.json``."""
        return {"method": "isoline",
                "iterations": int(self.iterations), "converged": bool(self.converged),
                "max_abs_z_mm": float(self.max_abs_z_mm),
                "flipped_triangles": int(self.flipped_triangles),
                "overlapping": bool(self.overlapping),
                "invalid_edge_fraction": float(self.invalid_edge_fraction),
                "invalid_area_fraction": float(self.invalid_area_fraction),
                "stretch_area_fraction": float(self.stretch_area_fraction),
                "overshrink_area_fraction": float(self.overshrink_area_fraction),
                "sigma": {k: float(v) for k, v in self.sigma_stats.items()},
                "bridge_strain": {k: float(v) for k, v in self.bridge_strain.items()}}


def flatten(mesh, s_min=0.0, s_max=0.343, iterations=50, weights=None, tol=1e-4,
            planar_iterations=50, planar_tol=1e-5, anderson=5, callback=None):
    """Flatten ``mesh`` (a :class:`pipeline.geometry.Mesh`, mm) into the plane.

    Parameters
    ----------
    mesh : Mesh
        Target surface with printing and bridge edges.
    s_min, s_max : float
        Shrink range of the material; printing edges may grow to
        l0/(1-s_min)..l0/(1-s_max).
    iterations : int
        Maximum relocation iterations (paper: 20-50).
    weights : dict, optional
        Overrides of :data:`DEFAULT_WEIGHTS`.
    tol : float
        Stop when the largest vertex move of an iteration falls below
        ``tol`` times the mean target edge length.
    planar_iterations : int
        Maximum in-plane PD iterations after setting z = 0.
    planar_tol : float
        The in-plane phase stops when no vertex moves more than this times
        the mean target edge length.
    anderson : int
        Anderson acceleration window of the in-plane phase (0: plain PD).
    callback : callable(iteration, positions), optional
        Called after every iteration with the (n, 3) (then (n, 2)) positions.

    Returns
    -------
    FlatResult
    """
    t0 = time.perf_counter()
    w = dict(DEFAULT_WEIGHTS)
    if weights:
        unknown = set(weights) - set(w)
        if unknown:
            raise ValueError(f"unknown flatten weights: {sorted(unknown)}")
        w.update(weights)
    V = np.asarray(mesh.vertices, dtype=float)
    top = topology(mesh.faces, len(V))
    l0 = edge_lengths(V, top.edges)
    is_print, print_row = _printing_mask(top.edges, mesh.printing_edges)
    lo, hi = l0.copy(), l0.copy()
    lo[is_print] = l0[is_print] / (1.0 - s_min)
    hi[is_print] = l0[is_print] / (1.0 - s_max)
    edge_w = np.where(is_print, w["printing"], w["bridge"])
    system = PDSystem(top, EdgeTargets(lo, hi, edge_w, l0), l0,
                      w_bending=w["bending"], w_shear=w["shear"])
    reloc = Relocator(top, w["flattening"], w["stretching"], w["spreading"])
    scale = float(l0.mean())
    t1 = time.perf_counter()

    X = np.ascontiguousarray(V.T)  # (3, n): the solver works component-major
    energy = []
    converged = False
    it = 0
    for it in range(1, iterations + 1):
        X_new, E = system.step(X)
        energy.append(E)
        X_new = reloc.apply(X_new, rate=flattening_rate(it, iterations, w["flattening"]))
        change = float(np.abs(X_new - X).max()) / scale
        X = X_new
        if callback is not None:
            callback(it, X.T)
        if change < tol:
            converged = True
            break
    max_abs_z = float(np.abs(X[2]).max())
    t2 = time.perf_counter()

    Y = np.ascontiguousarray(X[:2])
    if planar_iterations:
        Y, e_planar, _, _ = minimize(system, Y, planar_iterations, planar_tol * scale, planar=True,
                                     anderson=anderson, callback=callback, start=it)
        energy += e_planar
    Y = Y.T - Y.mean(axis=1)
    t3 = time.perf_counter()

    res = layout_quality(mesh, Y, top=top, s_min=s_min, s_max=s_max,
                         is_print=is_print, print_row=print_row)
    return FlatResult(xy=Y, iterations=it, converged=converged, max_abs_z_mm=max_abs_z,
                      energy_history=energy,
                      timing_s={"setup": t1 - t0, "iterate": t2 - t1, "planar": t3 - t2,
                                "total": time.perf_counter() - t0},
                      **res)


def flattening_rate(k, iterations, w_flattening, ramp=0.8):
    """Fraction of its height each vertex loses in iteration ``k`` (1-based).

    A linear ramp: each step removes 1/(steps left) of the height, aiming at
    z = 0 by ``ramp * iterations``, but never more than ``w_flattening`` (the
    paper's rate), which then keeps pressing to the end. Since each step
    takes a fraction, z never reaches exactly 0: what stays out of the plane
    is what the constraints push back out (wrinkles where the layout is
    compressed), and ``max_abs_z_mm`` reports it. The paper's constant rate
    from the first step presses a curved sheet flat before the constraints
    can spread it (summits crush and flip on fine meshes); the ramp moves at
    constant speed instead.
    """
    ramp_end = max(int(np.ceil(ramp * iterations)), 1)
    return min(float(w_flattening), 1.0 / max(ramp_end - k + 1, 1))


def _printing_mask(edges, printing_edges):
    """Mask over ``edges`` of printing edges and, per printing edge, its row in ``edges``."""
    row = edge_index(edges, printing_edges) if len(printing_edges) else np.zeros(0, np.int64)
    if (row < 0).any():
        raise ValueError("printing edge not in the mesh's faces")
    mask = np.zeros(len(edges), bool)
    mask[row] = True
    return mask, row


class Relocator:
    """The paper's three relocations (6.2.2), vectorised with bincount.

    Parameters
    ----------
    top : Topology
    w_flattening, w_stretching, w_spreading : float
    """

    def __init__(self, top, w_flattening, w_stretching, w_spreading):
        self.top = top
        self.wf, self.wst, self.wsp = float(w_flattening), float(w_stretching), float(w_spreading)
        n, faces = top.n, top.faces
        self.corner_v = faces.ravel()
        # Corners whose opposite edge is interior take part in spreading.
        opp_edge = top.face_edge.ravel()
        interior = (top.edge_faces[opp_edge] >= 0).all(axis=1)
        self.spread_corner = np.flatnonzero(interior)
        self.spread_count = np.maximum(
            np.bincount(self.corner_v[self.spread_corner], minlength=n), 1)
        be = top.edges[top.boundary_edges]
        self.bnd_v = np.unique(be)
        self.bnd_ends = be.ravel()
        self.bnd_count = np.maximum(np.bincount(self.bnd_ends, minlength=n), 1)
        # Contiguous index arrays, fixed per mesh: gathers through strided
        # columns or recomputed indices cost a third of each call.
        self.f0, self.f1, self.f2 = (np.ascontiguousarray(faces[:, k]) for k in range(3))
        self.e0, self.e1 = (np.ascontiguousarray(top.edges[:, k]) for k in range(2))
        self.fe0, self.fe1, self.fe2 = (np.ascontiguousarray(top.face_edge[:, k]) for k in range(3))
        self.spread_face = self.spread_corner // 3
        self.spread_v = self.corner_v[self.spread_corner]
        self.spread_opp = top.face_edge.ravel()[self.spread_corner]
        on_bnd = np.zeros(n, bool)
        on_bnd[self.bnd_v] = True
        bnd_corner = np.flatnonzero(on_bnd[self.corner_v])
        self.bnd_corner_v = self.corner_v[bnd_corner]
        self.bnd_corner_face = bnd_corner // 3

    def apply(self, X, rate=None):
        """Relocated copy of ``X`` ((3, n) mm, component-major).

        ``rate`` overrides the flattening fraction of this iteration.
        """
        top, n = self.top, self.top.n
        rate = self.wf if rate is None else rate
        Y = X.copy()
        Y[2] -= rate * X[2]
        wst, wsp = self.wst, self.wsp
        if wst == 0 and wsp == 0:
            return Y
        x, y, z = X
        f0, f1, f2 = self.f0, self.f1, self.f2
        ax, ay, az = x[f1] - x[f0], y[f1] - y[f0], z[f1] - z[f0]
        bx, by, bz = x[f2] - x[f0], y[f2] - y[f0], z[f2] - z[f0]
        # 2 * area * unit normal; only its x, y and norm are needed.
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        a2 = np.sqrt(nx * nx + ny * ny + nz * nz)
        e0, e1 = self.e0, self.e1
        dx, dy, dz = x[e1] - x[e0], y[e1] - y[e0], z[e1] - z[e0]
        el = np.sqrt(dx * dx + dy * dy + dz * dz)
        if wst:
            # Area-weighted mean of unit normals = sum(2A n) / sum(2A).
            # Only boundary vertices move; their corners are summed in mesh order as before.
            cv, fb = self.bnd_corner_v, self.bnd_corner_face
            vnx = np.bincount(cv, nx[fb], n)
            vny = np.bincount(cv, ny[fb], n)
            va = np.bincount(cv, a2[fb], n)
            bl = np.bincount(self.bnd_ends, np.repeat(el[top.boundary_edges], 2), n) / self.bnd_count
            v = self.bnd_v
            k = wst * bl[v] / np.maximum(va[v], 1e-300)
            Y[0, v] += k * vnx[v]
            Y[1, v] += k * vny[v]
        if wsp:
            inv = 1.0 / np.maximum(a2, 1e-300)
            perimeter = el[self.fe0] + el[self.fe1] + el[self.fe2]
            f = self.spread_face
            # Mean length of the two edges at each corner: half of the perimeter less the opposite edge.
            k = wsp * (0.5 * (perimeter[f] - el[self.spread_opp])) * inv[f]
            v = self.spread_v
            Y[0] += np.bincount(v, k * nx[f], n) / self.spread_count
            Y[1] += np.bincount(v, k * ny[f], n) / self.spread_count
        return Y


def layout_quality(mesh, xy, top=None, s_min=0.0, s_max=0.343, is_print=None, print_row=None):
    """Quality figures of a flat layout ``xy`` ((n, 2) mm) of ``mesh``.

    Returns a dict with ``sigma``, ``flipped_triangles``,
    ``boundary_intersections``, ``overlapping``, ``invalid_edge_fraction``,
    ``sigma_stats`` and ``bridge_strain`` (see :class:`FlatResult`).
    """
    V = np.asarray(mesh.vertices, dtype=float)
    top = topology(mesh.faces, len(V)) if top is None else top
    if is_print is None:
        is_print, print_row = _printing_mask(top.edges, mesh.printing_edges)
    l0 = edge_lengths(V, top.edges)
    lf = edge_lengths(xy, top.edges)
    sigma = 1.0 - l0[print_row] / lf[print_row]
    strain = lf[~is_print] / l0[~is_print] - 1.0
    target = signed_areas_2d(V, top.faces)
    orient = 1.0 if target.sum() >= 0 else -1.0
    flipped = int(np.count_nonzero(signed_areas_2d(xy, top.faces) * orient <= 0))
    crossings = boundary_intersections(xy, top.edges[top.boundary_edges])
    invalid = (sigma < s_min - SIGMA_TOL) | (sigma > s_max + SIGMA_TOL)
    areas = _invalid_areas(top, print_row, sigma < s_min - SIGMA_TOL,
                           sigma > s_max + SIGMA_TOL, np.abs(signed_areas_2d(xy, top.faces)))
    return {"sigma": sigma, "flipped_triangles": flipped, **areas,
            "boundary_intersections": crossings, "overlapping": bool(flipped or crossings),
            "invalid_edge_fraction": float(invalid.mean()) if len(sigma) else 0.0,
            "sigma_stats": _stats(sigma),
            "bridge_strain": {"mean_abs": float(np.abs(strain).mean()) if len(strain) else 0.0,
                              "max_abs": float(np.abs(strain).max()) if len(strain) else 0.0}}


def _invalid_areas(top, print_row, stretch, over, area):
    """Shares of the flat sheet's area in triangles with a printing edge that would have to
    stretch, or shrink more than the material can: the isoline method's counterpart of
    the free layout's invalid area (a triangle counts once, stretch first)."""
    edge_stretch = np.zeros(len(top.edges), bool)
    edge_over = np.zeros(len(top.edges), bool)
    edge_stretch[print_row] = stretch
    edge_over[print_row] = over
    f_stretch = edge_stretch[top.face_edge].any(axis=1)
    f_over = edge_over[top.face_edge].any(axis=1) & ~f_stretch
    total = max(float(area.sum()), 1e-12)
    return {"stretch_area_fraction": float(area[f_stretch].sum() / total),
            "overshrink_area_fraction": float(area[f_over].sum() / total),
            "invalid_area_fraction": float(area[f_stretch | f_over].sum() / total)}


def _stats(x):
    if len(x) == 0:
        return {"min": 0.0, "p05": 0.0, "mean": 0.0, "p95": 0.0, "max": 0.0}
    p05, p95 = np.percentile(x, [5, 95])
    return {"min": float(x.min()), "p05": float(p05), "mean": float(x.mean()),
            "p95": float(p95), "max": float(x.max())}


def boundary_intersections(xy, segments):
    """Number of crossing pairs among ``segments`` ((s, 2) int) in the plane.

    Segments sharing a vertex are not compared. Candidates come from a grid
    hash with cells at least as long as the longest segment, so each segment
    touches at most 2 x 2 cells; only pairs within a cell are tested.
    """
    if len(segments) < 4:
        return 0
    a, b = xy[segments[:, 0]], xy[segments[:, 1]]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    cell = max(float((hi - lo).max()), 1e-9) * 1.0001
    origin = lo.min(axis=0)
    i0 = np.floor((lo - origin) / cell).astype(np.int64)
    i1 = np.floor((hi - origin) / cell).astype(np.int64)
    ncol = int(i1[:, 1].max()) + 2
    keys, segs = [], []
    for cx in (i0[:, 0], i1[:, 0]):
        for cy in (i0[:, 1], i1[:, 1]):
            keys.append(cx * ncol + cy)
            segs.append(np.arange(len(segments)))
    keys, segs = np.concatenate(keys), np.concatenate(segs)
    uniq = np.unique(np.stack([keys, segs], axis=1), axis=0)
    keys, segs = uniq[:, 0], uniq[:, 1]
    pairs = []
    # Pairs within a cell: compare each entry with the next k entries of the sorted list.
    k = 1
    while True:
        same = keys[k:] == keys[:-k]
        if not same.any():
            break
        pairs.append(np.stack([segs[:-k][same], segs[k:][same]], axis=1))
        k += 1
    if not pairs:
        return 0
    pairs = np.unique(np.sort(np.concatenate(pairs), axis=1), axis=0)
    s, t = segments[pairs[:, 0]], segments[pairs[:, 1]]
    share = (s[:, :1] == t).any(axis=1) | (s[:, 1:] == t).any(axis=1)
    pairs = pairs[~share]
    p1, p2 = a[pairs[:, 0]], b[pairs[:, 0]]
    q1, q2 = a[pairs[:, 1]], b[pairs[:, 1]]
    d1 = _orient(q1, q2, p1)
    d2 = _orient(q1, q2, p2)
    d3 = _orient(p1, p2, q1)
    d4 = _orient(p1, p2, q2)
    cross = (d1 * d2 < 0) & (d3 * d4 < 0)
    return int(np.count_nonzero(cross))


def _orient(a, b, c):
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
