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

from pipeline.geometry import face_sides

# Jacobi sweeps of the stripe energy on the split triangles: on the real tiles 10 gave
# the coverage and overlap of a full solve there (30 and 100 no better).
RELAX_SWEEPS = 10
# Splits of the triangles a fork or branch leaves bare: each quarters the bare patch.
FORK_SPLITS = 2


def split(xy, faces, phase, X, width_mm, red):
    """Split the triangles ``red`` ((m,) bool) in four, and in two those of their
    neighbours that share one split side (:func:`split_mesh`).

    Each new vertex, the midpoint of a side from ``a`` to ``b``, takes the line field
    ``X[a] + X[b]`` (turned to agree) and the phase of ``a`` plus half the side's step,
    so the paths through a triangle split in two run where they did.

    Returns (xy, faces, phase, X, parent: (m2,) the input triangle of each)."""
    xy2, faces2, parent, sides = split_mesh(xy, faces, red)
    phase2, X2 = carry(xy, phase, X, sides, width_mm)
    return xy2, faces2, phase2, X2, parent


def split_mesh(xy, faces, red):
    """The triangles ``red`` ((m,) bool) split in four at their sides' midpoints, and in
    two those of their neighbours that share one split side (three-way splits would need
    more, so a neighbour with two split sides is split in four too).

    Returns (xy (n2, 2), faces (m2, 3), parent: (m2,) the input triangle of each, sides:
    (n2 - n, 2) the two ends of the side each new vertex halves, in the order of
    :func:`pipeline.geometry.unique_edges`)."""
    n = len(xy)
    red = np.asarray(red, bool).copy()
    if not red.any():
        return xy, faces, np.arange(len(faces)), np.zeros((0, 2), np.int64)
    fe, edges = face_sides(faces)
    while True:
        marked = np.zeros(len(edges), bool)
        marked[fe[red].ravel()] = True
        count = marked[fe].sum(axis=1)
        more = ~red & (count >= 2)
        if not more.any():
            break
        red |= more
    me = np.flatnonzero(marked)
    mid = np.full(len(marked), -1)
    mid[me] = n + np.arange(len(me))
    sides = edges[me]
    mid, marked = mid[fe], marked[fe]
    xy2 = np.vstack([xy, 0.5 * (xy[sides[:, 0]] + xy[sides[:, 1]])])
    r = np.flatnonzero(red)
    A, B, C = faces[r].T
    ab, bc, ca = mid[r, 0], mid[r, 1], mid[r, 2]
    out = [np.stack(t, axis=1) for t in ((A, ab, ca), (ab, B, bc), (ca, bc, C), (ab, bc, ca))]
    parent = [r] * 4
    g = np.flatnonzero(~red & (count == 1))
    k = np.argmax(marked[g], axis=1)                   # the split side: corners k, k + 1
    i0, i1, i2 = faces[g, k], faces[g, (k + 1) % 3], faces[g, (k + 2) % 3]
    m = mid[g, k]
    out += [np.stack([i0, m, i2], axis=1), np.stack([m, i1, i2], axis=1)]
    parent += [g, g]
    keep = np.flatnonzero(count == 0)
    out.append(faces[keep])
    parent.append(keep)
    return xy2, np.concatenate(out), np.concatenate(parent), sides


def carry(xy, phase, X, sides, width_mm):
    """``phase`` and ``X`` ((n,), (n, 2)) with values appended for the midpoints of
    ``sides`` ((k, 2) vertex ids, :func:`split_mesh`): ((n + k,), (n + k, 2))."""
    from pipeline.paths.stripes import _wrap

    a, b = sides[:, 0], sides[:, 1]
    s = np.where(np.einsum("ec,ec->e", X[a], X[b]) < 0, -1.0, 1.0)
    om = 2 * np.pi / width_mm * np.einsum("ec,ec->e", xy[b] - xy[a],
                                          0.5 * (X[a] + s[:, None] * X[b]))
    step = om + _wrap(s * phase[b] - phase[a] - om)
    Xm = X[a] + s[:, None] * X[b]
    Xm /= np.maximum(np.linalg.norm(Xm, axis=1), 1e-12)[:, None]
    return np.concatenate([phase, _wrap(phase[a] + step / 2)]), np.vstack([X, Xm])


def relax(sheet, normal, phase, X, width_mm, sweeps=RELAX_SWEEPS):
    """``sweeps`` Jacobi sweeps of the stripe energy of :func:`pipeline.paths.stripes.
    stripe_phase` from ``phase`` (given along ``X``), on the triangles of ``sheet``
    (:class:`pipeline.paths.sheet.Sheet`) with the line field ``normal`` per triangle.
    Returns (phase, X) as ``stripe_phase``."""
    from pipeline.paths.stripes import stripe_matrix, vertex_line_field

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
    u and pathless of :func:`pipeline.paths.stripes.corner_phases` on these triangles)."""
    from pipeline.paths.stripes import corner_phases

    fine, parent, sides = sheet.quartered
    phase, X = carry(sheet.xy, phase, X, sides, width_mm)
    phase, X = relax(fine, normal[parent], phase, X, width_mm, sweeps)
    xy, sub = fine.xy, fine.faces
    u, pathless = corner_phases(xy, sub, phase, X, width_mm)
    for _ in range(fork_splits):
        if not pathless.any():
            break
        n = len(xy)
        xy, sub, phase, X, p = split(xy, sub, phase, X, width_mm, pathless > 0)
        parent = parent[p]
        # Triangles not split keep their corners' values: only the new ones are asked.
        new = (sub >= n).any(axis=1)
        u, pathless = u[p], pathless[p]
        u[new], pathless[new] = corner_phases(xy, sub[new], phase, X, width_mm)
    return xy, sub, phase, X, parent, u, pathless
