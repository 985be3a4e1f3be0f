"""Regions of the simulated sheet that popped the wrong way.

A sheet started flat in the bath chooses, region by region, which way to rise: a hill
can come out as a valley and a valley as a hill while the metric is right. Each point's
bump is its height above the sheet smoothed over a neighbourhood (a few rings of the
mesh); where the target clearly has a bump and the simulated sheet has one of the
other sign, that point settled inverted. Connected triangles of such points form the
regions reported; slivers below ``min_area_fraction`` of the sheet are left out.
"""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pipeline.geometry import unique_edges

RINGS = 8          # smoothing steps: the neighbourhood a bump is measured against
CLEAR = 0.2        # a target bump counts from this share of its 95th-percentile size


def inverted_regions(target, simulated, faces, min_area_fraction=0.01):
    """Regions where ``simulated`` bends the other way than ``target``.

    target, simulated : (n, 3) mm, the same vertices, the simulated sheet aligned to
    the target; faces : (m, 3) int. Returns a dict: ``regions`` (count),
    ``area_fraction`` (their share of the target's area), ``largest_mm2``, and
    ``faces`` ((m,) bool, the triangles in them).
    """
    faces = np.asarray(faces, dtype=np.int64)
    T = np.asarray(target, dtype=float)
    smooth = _smoother(faces, len(T))
    bump_t = _bump(T[:, 2], smooth)
    bump_s = _bump(np.asarray(simulated, dtype=float)[:, 2], smooth)
    clear = np.abs(bump_t) > CLEAR * max(np.percentile(np.abs(bump_t), 95), 1e-9)
    wrong = clear & (np.sign(bump_s) == -np.sign(bump_t)) & (np.abs(bump_s) > 0.25 * np.abs(bump_t))
    in_face = wrong[faces].all(axis=1)
    area = 0.5 * np.linalg.norm(np.cross(T[faces[:, 1]] - T[faces[:, 0]],
                                         T[faces[:, 2]] - T[faces[:, 0]]), axis=1)
    # An inverted hill is its crown and, a few millimetres out, its skirt turned the
    # other way: joined across the rim between them, they are one region.
    near = wrong.copy()
    for _ in range(RINGS // 2):
        near = (smooth @ near.astype(float)) > 0
    label = _face_components(faces, near[faces].all(axis=1))
    sizes = np.bincount(label[in_face], weights=area[in_face], minlength=max(label.max() + 1, 1))
    keep = (sizes > 0) & (sizes >= min_area_fraction * area.sum())
    chosen = in_face & keep[np.maximum(label, 0)]
    return {"regions": int(keep.sum()),
            "area_fraction": float(area[chosen].sum() / max(area.sum(), 1e-12)),
            "largest_mm2": float(sizes[keep].max()) if keep.any() else 0.0,
            "faces": chosen}


def _smoother(faces, n):
    """Row-normalised vertex adjacency (with the vertex itself): (n, n) sparse."""
    E = unique_edges(faces)
    i = np.r_[E[:, 0], E[:, 1], np.arange(n)]
    j = np.r_[E[:, 1], E[:, 0], np.arange(n)]
    A = sp.csr_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    return sp.diags(1.0 / np.asarray(A.sum(axis=1)).ravel()) @ A


def _bump(z, smooth):
    """Height above the surroundings: ``z`` less its smoothing over ``RINGS`` steps."""
    s = z.copy()
    for _ in range(RINGS):
        s = smooth @ s
    return z - s


def _face_components(faces, mask):
    """Component label of each masked face over shared edges (-1 elsewhere)."""
    m = len(faces)
    sides = np.sort(np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], 1)
                    .reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(m), 3)
    keep = mask[owner]
    sides, owner = sides[keep], owner[keep]
    order = np.lexsort((sides[:, 1], sides[:, 0]))
    sides, owner = sides[order], owner[order]
    same = np.all(sides[1:] == sides[:-1], axis=1)
    a, b = owner[:-1][same], owner[1:][same]
    graph = sp.csr_matrix((np.ones(len(a)), (a, b)), shape=(m, m))
    _, label = connected_components(graph, directed=False)
    return np.where(mask, label, -1)


def settled_inverted(sim, mesh):
    """:func:`inverted_regions` of a plan's simulation, on the sheet it was simulated on."""
    target = mesh.vertices if sim.target is None else sim.target
    faces = mesh.faces if sim.faces is None else sim.faces
    return inverted_regions(target, sim.vertices, faces)


def report(found):
    """The report's ``simulation.inverted``: the figures without the triangle mask."""
    return {k: v for k, v in found.items() if k != "faces"}


def problems(found, name):
    """A warning when some region of the sheet settled the other way up."""
    if not found["regions"]:
        return []
    return [{"code": "simulate.inverted",
             "message": "%d region%s of the simulated sheet (%.0f %% of it, the largest %.0f "
                        "mm2) rose the other way than the target: a hill as a pit or a valley "
                        "as a ridge" % (found["regions"], "s" if found["regions"] > 1 else "",
                                         100 * found["area_fraction"], found["largest_mm2"]),
             "fix": "%s.preview.png shows where; in the bath a light push from below (or "
                    "above) as the sheet rises sets such a region the right way" % name}]
