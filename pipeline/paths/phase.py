"""The stripe phase's pieces that the solve on the layout's triangles
(:mod:`pipeline.paths.stripes`) and its carrying to finer ones (:mod:`pipeline.paths.refine`)
share: the line field at the vertices, the stripe energy and each triangle's corner values
of the path index."""

import numpy as np


# Why a triangle holds no path (see :func:`corner_phases`).
FORK, BRANCH = 1, 2


def vertex_line_field(sheet, normal):
    """Per-vertex unit line field from per-face ``normal`` ((m, 2) unit) on ``sheet``
    (:class:`pipeline.paths.sheet.Sheet`): area-weighted mean of the doubled angles.
    Returns (n, 2)."""
    z = sheet.face_area * np.exp(2j * np.arctan2(normal[:, 1], normal[:, 0]))
    acc = np.zeros(len(sheet.xy), complex)
    np.add.at(acc, sheet.faces.ravel(), np.repeat(z, 3))
    ang = np.angle(acc) / 2
    return np.stack([np.cos(ang), np.sin(ang)], axis=1)


def stripe_matrix(sheet, X, width_mm):
    """The stripe energy of a phase along the vertex field ``X`` ((n, 2) unit) on
    ``sheet`` (:class:`pipeline.paths.sheet.Sheet`): the sparse (2n, 2n) matrix over the
    real and imaginary parts of the vertex values, and its diagonal per vertex ((n,))."""
    i, j = sheet.edges.T
    s, omega = edge_steps(sheet.edge_vectors, X[i], X[j], width_mm)
    w = sheet.weights
    c, sn = w * np.cos(omega), w * np.sin(omega)
    # Transport of vertex i's value to j: rotation by omega, then conjugation if the
    # line field turns over along the edge, T = [[c, -sn], [s sn, s c]]; A_ji = -w T.
    block = -np.stack([c, -sn, s * sn, s * c])
    diag = sheet.weight_sums
    return sheet.matrix(block, diag), diag


def edge_steps(d, Xa, Xb, width_mm):
    """Along edges ``d`` ((e, 2) mm, from end a to end b) with the line field ``Xa``,
    ``Xb`` ((e, 2) unit) at their ends: the sign that turns ``Xb`` to agree with ``Xa``
    ((e,) +-1) and the phase a stripe pattern ``width_mm`` apart advances by along
    each edge ((e,) rad)."""
    s = np.where(np.einsum("ec,ec->e", Xa, Xb) < 0, -1.0, 1.0)
    omega = 2 * np.pi / width_mm * np.einsum("ec,ec->e", d, 0.5 * (Xa + s[:, None] * Xb))
    return s, omega


def corner_phases(xy, faces, phase, X, width_mm):
    """Each triangle's three corner values of the path index (phase / 2 pi), unwrapped
    in the triangle's own orientation of the line field: (m, 3), and why a triangle
    holds no path ((m,) int8): 0 it holds paths, ``FORK`` the phase winds around it (a
    fork of the stripes, where one path ends between two), ``BRANCH`` the line field
    turns over in it."""
    xy = np.asarray(xy, dtype=float)
    # Component by component, (m, 3) each: the (m, 3, 2) corner arrays and their
    # einsums took twice as long, for the same sums.
    fx, fy = X[:, 0][faces], X[:, 1][faces]
    sign = np.where(fx * fx[:, :1] + fy * fy[:, :1] < 0, -1.0, 1.0)
    lx, ly = fx * sign, fy * sign
    ph = phase[faces] * sign
    px, py = xy[:, 0][faces], xy[:, 1][faces]
    scale = 2 * np.pi / width_mm
    u = np.zeros(ph.shape)
    total = np.zeros(len(faces))
    for k in range(3):
        a, b = k, (k + 1) % 3
        om = scale * ((px[:, b] - px[:, a]) * (0.5 * (lx[:, a] + lx[:, b]))
                      + (py[:, b] - py[:, a]) * (0.5 * (ly[:, a] + ly[:, b])))
        step = om + _wrap(ph[:, b] - ph[:, a] - om)
        if b != 0:
            u[:, b] = u[:, a] + step
        total += step
    u = (u + ph[:, :1]) / (2 * np.pi)
    turn = [fx[:, k] * fx[:, (k + 1) % 3] + fy[:, k] * fy[:, (k + 1) % 3] for k in range(3)]
    branch = turn[0] * turn[1] * turn[2] < 0
    winding = np.abs(np.rint(total / (2 * np.pi))) > 0
    return u, np.where(branch, BRANCH, np.where(winding, FORK, 0)).astype(np.int8)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi
