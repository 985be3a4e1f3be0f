"""Forward simulation with the thin-shell model: the answer is the sheet's, not the mesh's.

The flat sheet is given, per triangle, the shape it has once shrunk (its rest side
lengths) and its printed thickness; :class:`pipeline.mechanics.shell.ShellSystem`
weighs stretching by ``h * area`` and bending by ``h^3 / 12``, so the balance of
the two is the sheet's and converges as the mesh is refined. The sheet settles to
rest under :func:`pipeline.mechanics.pd.minimize_lbfgs` and is rigidly aligned to
the target, as in :mod:`pipeline.simulation.forward`.

Either layout method gives the rest shapes: the isoline method's printing edges
shrunk by their sigma (:func:`isoline_rest`), or a free layout's per-triangle
shrink along its print direction (:func:`directional_rest`), or of its two layer groups
(:func:`tensor_rest`).
"""

import time

import numpy as np

from pipeline.geometry import edge_index, edge_lengths
from pipeline.mechanics.constraints import topology
from pipeline.mechanics.pd import minimize_lbfgs
from pipeline.mechanics.shell import ShellSystem, face_lengths
from pipeline.simulation.forward import SimResult, align, pop_profile

# Curvature pairs the shell's L-BFGS keeps. A shell's soft bending modes need a longer
# memory than the paper's spring sheet: with 20 instead of 5 a real 175 mm tile comes to
# rest in 458 iterations instead of 672, the starfish in 149 instead of 192 (the same
# shape within 0.04 mm); more than 20 gains no iterations and costs time per step.
LBFGS_MEMORY = 20


def isoline_rest(mesh, xy, s_min=None, s_max=None):
    """Rest side lengths of the isoline method's sheet after the bath.

    Printing edges shrink by their sigma (clamped to ``[s_min, s_max]``, as printed),
    bridge edges keep their flat length. Returns (rest_len (m, 3) mm, opposite each
    corner; sigma (m,) the mean clamped sigma of each triangle's printing edges, 0
    where it has none; clamped, the count of printing edges clamped).
    """
    V = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    pe = np.asarray(mesh.printing_edges, dtype=np.int64).reshape(-1, 2)
    l_flat = edge_lengths(xy, pe)
    sigma = 1.0 - edge_lengths(V, pe) / np.maximum(l_flat, 1e-12)
    lo = -np.inf if s_min is None else s_min
    hi = np.inf if s_max is None else s_max
    clamped = int(np.count_nonzero((sigma < lo) | (sigma > hi)))
    sigma = np.clip(sigma, lo, hi)
    rest = face_lengths(np.c_[xy, np.zeros(len(xy))], faces)
    # Side k of a face joins corners k+1 and k+2.
    sides = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1)
    which = edge_index(pe, np.sort(sides.reshape(-1, 2), axis=1)).reshape(-1, 3)
    printing = which >= 0
    s_side = np.where(printing, sigma[np.maximum(which, 0)], 0.0)
    rest *= 1.0 - s_side
    count = printing.sum(axis=1)
    s_face = np.where(count > 0, s_side.sum(axis=1) / np.maximum(count, 1), 0.0)
    return rest, s_face, clamped


def directional_rest(xy, faces, direction, sigma):
    """Rest side lengths of a sheet whose triangles shrink by ``sigma`` along ``direction``.

    xy : (n, 2) mm flat layout; faces : (m, 3); direction : (m, 2) unit, layout
    coordinates; sigma : (m,). Returns rest_len (m, 3) mm, opposite each corner.
    """
    sides = _sides(xy, faces)
    d = np.asarray(direction, dtype=float)
    along = np.einsum("fkc,fc->fk", sides, d)
    shrunk = sides - (np.asarray(sigma, dtype=float)[:, None] * along)[:, :, None] * d[:, None, :]
    return np.linalg.norm(shrunk, axis=2)


def tensor_rest(xy, faces, shrink):
    """Rest side lengths of a sheet whose triangles shrink by the tensor ``shrink``
    ((m, 2, 2), layout coordinates: a side ``v`` becomes ``v - shrink v``; two layer
    groups along their own directions shrink by their mean). Returns (m, 3) mm."""
    sides = _sides(xy, faces)
    shrunk = sides - np.einsum("mij,mkj->mki", np.asarray(shrink, dtype=float), sides)
    return np.linalg.norm(shrunk, axis=2)


def _sides(xy, faces):
    """Each triangle's sides in the layout, opposite each corner: (m, 3, 2) mm."""
    P = np.asarray(xy, dtype=float)[faces]
    return P[:, [2, 0, 1]] - P[:, [1, 2, 0]]


def thickness_for(sigma_face, shrink, layers, lo_mm, hi_mm):
    """Printed thickness of each triangle: ``layers`` layers of the thickness that
    gives its shrink (the profile's curve, clamped to its range): (m,) mm."""
    theta, _ = shrink.theta(np.asarray(sigma_face, dtype=float))
    return layers * np.clip(theta, lo_mm, hi_mm)


def simulate_shell(vertices, faces, xy, rest_len, thickness_mm, theta_rest=None, pop=0.15,
                   iterations=600, rest_tol=2e-5, callback=None, clamped=0, ramp=(1.0,),
                   start=None):
    """Let the flat sheet take its rest shapes and settle; compare with the target.

    Parameters
    ----------
    vertices : (n, 3) mm, the target; faces : (m, 3) int; xy : (n, 2) mm, the layout
    rest_len : (m, 3) mm, each triangle's side lengths after the bath
    thickness_mm : (m,) printed thickness
    theta_rest : (h,) rad, optional, programmed rest dihedral angles
    pop : start bump as a fraction of the layout's diameter (0: start flat)
    iterations : cap of L-BFGS iterations, per ramp stage
    rest_tol : at rest when the sheet moved less than this times the layout's
        diameter (RMS) over ten iterations
    ramp : fractions of the shrink (and programmed curvature) the sheet settles
        under in turn, each from the last one's shape: the bath heats a sheet
        gradually, and a sheet shrunk all at once from flat can buckle into a
        state the gradual one never reaches
    start : (n, 3) mm, optional, the shape to settle from instead of the flat sheet

    Returns
    -------
    SimResult (``coarse_iterations`` 0, ``sheet_vertices`` every vertex)
    """
    t0 = time.perf_counter()
    V = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    xy = np.asarray(xy, dtype=float)
    diameter = float(np.linalg.norm(xy.max(axis=0) - xy.min(axis=0)))
    X = np.zeros((3, len(V)))
    X[:2] = xy.T
    X[2] = pop_profile(xy, topology(faces, len(V)), pop)
    if start is not None:
        X = np.array(start, dtype=float).T
    flat_len = face_lengths(np.c_[xy, np.zeros(len(xy))], faces)
    energy, it = [], 0
    for t in ramp:
        system = ShellSystem(faces, len(V), flat_len + t * (np.asarray(rest_len) - flat_len),
                             thickness_mm, theta_rest)
        X, e, i, converged = minimize_lbfgs(system, X, iterations, rest_tol * diameter,
                                            memory=LBFGS_MEMORY, callback=callback)
        energy += e
        it += i
    P = X.T
    aligned, disp = align(P, V)
    mirrored = False
    if theta_rest is None:
        # Without a programmed curvature every energy is invariant under z -> -z:
        # the mirrored start settles into the mirror image (no second solve needed).
        aligned_m, disp_m = align(P * np.array([1.0, 1.0, -1.0]), V)
        mirrored = bool(disp_m.mean() < disp.mean())
        if mirrored:
            aligned, disp = aligned_m, disp_m
    total = time.perf_counter() - t0
    return SimResult(vertices=aligned, displacement_mm=disp,
                     mean_displacement_mm=float(disp.mean()),
                     max_displacement_mm=float(disp.max()), iterations=it,
                     converged=converged, mirrored=mirrored, clamped_edges=int(clamped),
                     sheet_vertices=len(V), coarse_iterations=0, energy_history=energy,
                     timing_s={"full": total, "total": total}, faces=faces, target=V)
