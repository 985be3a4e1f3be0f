"""The layout again, for the shrink the sheet is printed with.

The free layout gives each triangle one shrink, along its print direction, and keeps
its length across. The curvature program then prints more than that: a little extra
shrink along ``d`` where the bilayer needs room (:func:`pipeline.layout.curvature.
room_for`), and two layers across ``d`` that shrink the sheet across it by their shrink
over the layer count (:mod:`pipeline.layout.laminate`). Printed on the layout as
solved, the sheet after the bath is off the target's metric by those and settles off
the shape by them: on the starfish the programmed stack on its own metric rests 0.54 %
of the diameter off, the same curvature on the layout's metric 0.31 %.

:func:`relaid` solves the layout once more, from the first, with the program's shrink
given: each triangle's map keeps the stretch ``1 / (1 - across)`` across ``d`` (the
layers across shrink the sheet that much), and its stretch along ``d`` at least
``1 / (1 - min_shrink)`` (the room). Free layout's local/global iterations, with the
print direction followed from the first layout (the singular vector nearest it) rather
than taken as the larger stretch, which it need not be where only the layers across
shrink.
"""

import numpy as np

from pipeline.layout.free import global_system, jacobians, local_global

ITERATIONS = 60
# Singular values this far apart name the direction the layout stretches along.
DISTINCT = 0.01


def relaid(vertices, faces, xy, direction, across, min_shrink, s_min, s_max,
           iterations=ITERATIONS, tol=1e-6):
    """The free layout with the program's shrink across ``d`` and room along it.

    vertices : (n, 3) mm, the target; faces : (m, 3); xy : (n, 2) mm, the first layout
    (the start); direction : (m, 2) unit, its print directions; across : (m,) the
    sheet's shrink across ``d``; min_shrink : (m,) the least shrink along ``d``;
    s_min, s_max : the printable range along ``d``.
    Returns (xy (n, 2) mm, direction (m, 2) unit, sigma (m,) the shrink along it,
    {iterations, residual, max_move_mm}).
    """
    V = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    m = len(faces)
    system = global_system(V, faces)
    lam_lo = 1.0 / (1.0 - np.maximum(s_min, np.asarray(min_shrink, dtype=float)))
    lam_hi = 1.0 / (1.0 - s_max)
    a = 1.0 / (1.0 - np.asarray(across, dtype=float))
    X0 = np.asarray(xy, dtype=float)
    # Each projection labels the print direction from the one before.
    d = [np.asarray(direction, dtype=float)]

    def labelled(J):
        P, _, d[0] = _project_labelled(J, d[0], lam_lo, lam_hi, a)
        return P
    X, it, residual, _ = local_global(system, X0.copy(), labelled, iterations, tol)
    _, lam, d = _project_labelled(jacobians(system[0], X, m), d[0], lam_lo, lam_hi, a)
    return X, d, 1.0 - 1.0 / lam, {"iterations": it, "residual": residual,
                                    "max_move_mm": float(np.abs(X - X0).max())}


def _project_labelled(J, d, lam_lo, lam_hi, a):
    """The nearest Jacobians with the stretch ``lambda`` in [lam_lo, lam_hi] along the
    print direction and ``a`` across it. Where ``J`` stretches one way more than the
    other (by :data:`DISTINCT`) the print direction is its singular vector nearest ``d``
    (a line: either sign); where it stretches nearly alike both ways the singular vectors
    are round-off, and ``d`` stays (the direction the program chose there), with the
    rotation nearest ``D^-1 J``, ``D = lambda d d^T + a e e^T``.
    Returns (P (m, 2, 2), lambda (m,), the print direction (m, 2) unit)."""
    along = _print_direction(J, d)
    x, y = along[:, 0], along[:, 1]
    # |J^T along|, the stretch along the print direction.
    lam = np.clip(_length(J[:, 0, 0] * x + J[:, 1, 0] * y, J[:, 0, 1] * x + J[:, 1, 1] * y),
                  lam_lo, lam_hi)
    a = np.broadcast_to(np.asarray(a, dtype=float), lam.shape)
    P = _stretched_rotation(J, along, lam, a)
    return P, lam, along


def _print_direction(J, d):
    """:func:`_project_labelled`'s print direction: (m, 2) unit, on the side of ``d``.
    Component arrays and no trigonometry: (m, 2) stacks, einsums, arctan2 and cos took
    half the local step, and each costs as much as forty products."""
    j00, j01, j10, j11 = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
    # _svd2_angles's left rotation, phi = (angle(F, G) + angle(E, H)) / 2, as a line:
    # the half of their sum up to sign (the side of d is chosen below).
    E, F = (j00 + j11) / 2, (j00 - j11) / 2
    G, H = (j10 + j01) / 2, (j10 - j01) / 2
    (c1, s1, R), (c2, s2, Q) = _unit(F, G), _unit(E, H)
    c, s = c1 * c2 - s1 * s2, s1 * c2 + c1 * s2
    # (1 + c, s) and (s, 1 - c) both lie along the half angle; take the longer.
    wide = c >= 0
    cp, sp, _ = _unit(np.where(wide, 1.0 + c, s), np.where(wide, s, 1.0 - c))
    dx, dy = d[:, 0], d[:, 1]
    # The first singular vector (cp, sp) or the second (-sp, cp), whichever is nearer d.
    first = np.abs(cp * dx + sp * dy) >= np.sqrt(0.5)
    distinct = (Q + R) - np.abs(Q - R) > DISTINCT
    ux = np.where(distinct, np.where(first, cp, -sp), dx)
    uy = np.where(distinct, np.where(first, sp, cp), dy)
    side = np.where(ux * dx + uy * dy < 0, -1.0, 1.0)
    along = np.empty_like(d)
    np.multiply(ux, side, out=along[:, 0])
    np.multiply(uy, side, out=along[:, 1])
    return along


def _stretched_rotation(J, d, lam, a):
    """``D R``, ``D = lam d d^T + a e e^T`` (``e`` across ``d``, (m, 2) unit) and ``R``
    the rotation nearest ``D^-1 J`` ((m, 2, 2)): (m, 2, 2). Written out per component:
    batched 2x2 solves and products took two thirds of the relaid layout's time on a
    real tile."""
    x, y = d[:, 0], d[:, 1]
    xx, yy, xy = x * x, y * y, x * y
    inv_l, inv_a = 1.0 / lam, 1.0 / a
    # D^-1 = D with the stretches inverted (d and e are orthonormal).
    i00, i01, i11 = inv_l * xx + inv_a * yy, (inv_l - inv_a) * xy, inv_l * yy + inv_a * xx
    j00, j01, j10, j11 = J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1]
    c, s, _ = _unit((i00 * j00 + i01 * j10) + (i01 * j01 + i11 * j11),
                 (i01 * j00 + i11 * j10) - (i00 * j01 + i01 * j11))
    d00, d01, d11 = lam * xx + a * yy, (lam - a) * xy, lam * yy + a * xx
    P = np.empty_like(J)
    P[:, 0, 0], P[:, 0, 1] = d00 * c + d01 * s, d01 * c - d00 * s
    P[:, 1, 0], P[:, 1, 1] = d01 * c + d11 * s, d11 * c - d01 * s
    return P


def _unit(x, y):
    """Cosine and sine of the angle of the vectors ``(x, y)`` ((m,) each), as
    ``arctan2`` gives it (0 for a zero vector), and their length: three (m,)."""
    r = _length(x, y)
    zero = r == 0
    if zero.any():
        x, y = np.where(zero, 1.0, x), np.where(zero, 0.0, y)
        return x / np.where(zero, 1.0, r), y / np.where(zero, 1.0, r), r
    return x / r, y / r, r


def _length(x, y):
    """``np.hypot`` for Jacobian entries, O(1): its guard against overflow costs as much
    as forty products."""
    return np.sqrt(x * x + y * y)
