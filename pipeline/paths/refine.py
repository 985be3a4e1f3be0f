"""Finer triangles for the stripe phase than the layout's.

The layout's triangles are about 2.6 path widths a side, while the free direction turns
by tens of degrees a millimetre on real terrain: the phase, linear along each edge,
cannot follow the paths between the corners, and the stripes fork in a fifth of the
triangles, each a bare patch. Solving again on triangles split in four took six times
as long; instead the coarse phase is carried to the split triangles (each edge's
midpoint gets the phase half way along the edge's step) and relaxed there by a few
sweeps of the same energy, which moves the forks to where the finer triangles put them
and straightens the paths between. The triangles the phase still winds around are then
split again, twice, without relaxing: the fork stays in one of the four, so the bare
patch shrinks to a sixteenth.
"""

import numpy as np

from pipeline.paths.phase import (_wrap, corner_phases, edge_steps, stripe_matrix,
                                  vertex_line_field)
from pipeline.paths.sheet import split_mesh

# Jacobi sweeps of the stripe energy on the split triangles: on the real tiles 10 gave
# the coverage and overlap of a full solve there (30 and 100 no better).
RELAX_SWEEPS = 10
# Splits of the triangles a fork or branch leaves bare: each quarters the bare patch.
FORK_SPLITS = 2


def split(xy, faces, phase, X, width_mm, red, sides=None):
    """Split the triangles ``red`` ((m,) bool) in four, and in two those of their
    neighbours that share one split side (:func:`pipeline.paths.sheet.split_mesh`;
    ``sides`` as it takes them).

    Each new vertex, the midpoint of a side from ``a`` to ``b``, takes the line field
    ``X[a] + X[b]`` (turned to agree) and the phase of ``a`` plus half the side's step,
    so the paths through a triangle split in two run where they did.

    Returns (xy, faces, phase, X, parent: (m2,) the input triangle of each)."""
    xy2, faces2, parent, sides = split_mesh(xy, faces, red, sides)
    phase2, X2 = carry(xy, phase, X, sides, width_mm)
    return xy2, faces2, phase2, X2, parent


def carry(xy, phase, X, sides, width_mm):
    """``phase`` and ``X`` ((n,), (n, 2)) with values appended for the midpoints of
    ``sides`` ((k, 2) vertex ids, :func:`pipeline.paths.sheet.split_mesh`): ((n + k,), (n + k, 2))."""
    a, b = sides[:, 0], sides[:, 1]
    s, om = edge_steps(xy[b] - xy[a], X[a], X[b], width_mm)
    step = om + _wrap(s * phase[b] - phase[a] - om)
    Xm = X[a] + s[:, None] * X[b]
    Xm /= np.maximum(np.linalg.norm(Xm, axis=1), 1e-12)[:, None]
    return np.concatenate([phase, _wrap(phase[a] + step / 2)]), np.vstack([X, Xm])


def relax(sheet, normal, phase, X, width_mm, sweeps=RELAX_SWEEPS):
    """``sweeps`` Jacobi sweeps of the stripe energy of :func:`pipeline.paths.stripes.
    stripe_phase` from ``phase`` (given along ``X``), on the triangles of ``sheet``
    (:class:`pipeline.paths.sheet.Sheet`) with the line field ``normal`` per triangle.
    Returns (phase, X) as ``stripe_phase``."""
    Xn = vertex_line_field(sheet, normal)
    # A vertex whose new line field points the other way sees the conjugate value.
    phase = np.where(np.einsum("nc,nc->n", Xn, X) < 0, -phase, phase)
    A, diag = stripe_matrix(sheet, Xn, width_mm)
    v = np.empty(2 * len(sheet.xy))
    v[0::2], v[1::2] = np.cos(phase), np.sin(phase)
    d = np.repeat(diag, 2)
    for _ in range(sweeps):
        v = v - (A @ v) / d
    return np.arctan2(v[1::2], v[0::2]), Xn


def refine_phase(sheet, normal, phase, X, width_mm, sweeps=RELAX_SWEEPS,
                 fork_splits=FORK_SPLITS):
    """The phase on every triangle of ``sheet`` (:class:`pipeline.paths.sheet.Sheet`)
    split in four and relaxed, then the triangles it winds around split
    ``fork_splits`` times more.

    Returns (xy, faces, phase, X, parent: (m2,) the input triangle of each,
    u and pathless of :func:`pipeline.paths.phase.corner_phases` on these triangles)."""
    fine, parent, sides = sheet.quartered
    phase, X = carry(sheet.xy, phase, X, sides, width_mm)
    phase, X = relax(fine, normal[parent], phase, X, width_mm, sweeps)
    xy, sub = fine.xy, fine.faces
    u, pathless = corner_phases(xy, sub, phase, X, width_mm)
    # The finer sheet's sides are known from its energy; those of its splits are not.
    sides = fine.face_edges, fine.edges
    for _ in range(fork_splits):
        if not pathless.any():
            break
        n = len(xy)
        xy, sub, phase, X, p = split(xy, sub, phase, X, width_mm, pathless > 0, sides)
        sides = None
        parent = parent[p]
        # Triangles not split keep their corners' values: only the new ones are asked.
        new = (sub >= n).any(axis=1)
        u, pathless = u[p], pathless[p]
        u[new], pathless[new] = corner_phases(xy, sub[new], phase, X, width_mm)
    return xy, sub, phase, X, parent, u, pathless
