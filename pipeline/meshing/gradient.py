"""Gradient lines between neighbouring isolines (paper 6.1, Dong et al. 2005).

Lines are integrated with height as the parameter, ``dx/dh = grad g / |grad g|^2``,
so a line started on the isoline at ``h0`` and integrated to ``h1`` ends on the
isoline at ``h1`` by construction; all seeds of a band advance together (RK4,
vectorised over seeds).
"""

import numpy as np
from scipy.spatial import cKDTree

# Smallest gradient (mm/mm) we divide by: flat spots would otherwise throw lines far.
_G_MIN = 1e-3


def trace(field, xy0, h_target, steps=6, max_step_mm=3.0):
    """Follow the guide field's gradient from ``xy0`` to the level ``h_target``.

    Parameters
    ----------
    field : GuideField
    xy0 : (q, 2) float, mm
    h_target : (q,) float or float, mm
    steps : int, RK4 steps per line

    Returns
    -------
    xy : (q, 2) float, mm, end points
    ok : (q,) bool, reached the level without leaving the footprint
    """
    x = np.array(xy0, dtype=float)
    q = len(x)
    if q == 0:
        return x, np.zeros(0, bool)
    target = np.broadcast_to(np.asarray(h_target, dtype=float), (q,))
    dh = (target - field.value(x)) / steps
    inside = field.inside.astype(float)
    ok = np.ones(q, bool)

    def f(p):
        g = field.gradient(p)
        n2 = np.maximum(np.einsum("ij,ij->i", g, g), _G_MIN ** 2)
        return g / n2[:, None]

    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + 0.5 * dh[:, None] * k1)
        k3 = f(x + 0.5 * dh[:, None] * k2)
        k4 = f(x + dh[:, None] * k3)
        step = dh[:, None] * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        length = np.linalg.norm(step, axis=1)
        ok &= length <= max_step_mm
        x = x + step
        ok &= field.sample(inside, x, order=0) > 0.5
    # Two Newton steps along the gradient remove the integration error in h.
    for _ in range(2):
        g = field.gradient(x)
        n2 = np.maximum(np.einsum("ij,ij->i", g, g), _G_MIN ** 2)
        x = x + ((target - field.value(x)) / n2)[:, None] * g
    ok &= np.abs(field.value(x) - target) < 0.02 + 0.01 * np.abs(dh) * steps
    ok &= field.sample(inside, x, order=0) > 0.5
    return x, ok


class Snapper:
    """Nearest point on a set of pieces (polylines), as (piece, arc-length t).

    Parameters
    ----------
    pieces : list of Piece
    ids : sequence of int, indices of the pieces to snap to
    """

    def __init__(self, pieces, ids):
        pts, owner, index = [], [], []
        for i in ids:
            p = pieces[i].points
            pts.append(p)
            owner.append(np.full(len(p), i))
            index.append(np.arange(len(p)))
        self.pieces = pieces
        if pts:
            self.points = np.concatenate(pts)
            self.owner = np.concatenate(owner)
            self.index = np.concatenate(index)
            self.tree = cKDTree(self.points)
        else:
            self.tree = None

    def snap(self, xy):
        """Returns ``(piece (q,) int, t (q,) float, dist (q,) float)``; piece -1 if none."""
        q = len(xy)
        if self.tree is None or q == 0:
            return np.full(q, -1), np.zeros(q), np.full(q, np.inf)
        _, j = self.tree.query(xy)
        piece_ids = self.owner[j]
        out_t = np.zeros(q)
        out_d = np.full(q, np.inf)
        # Project on the segments before and after the nearest vertex (grouped by piece).
        for pid in np.unique(piece_ids):
            sel = np.nonzero(piece_ids == pid)[0]
            pc = self.pieces[pid]
            pts = np.vstack([pc.points, pc.points[:1]]) if pc.closed else pc.points
            nseg = len(pts) - 1
            k = self.index[j[sel]]
            best_t = np.full(len(sel), np.nan)
            best_d = np.full(len(sel), np.inf)
            for s in (k - 1, k):
                valid = (s >= 0) & (s < nseg) if not pc.closed else np.ones(len(s), bool)
                s = np.mod(s, nseg)
                a, b = pts[s], pts[s + 1]
                ab = b - a
                L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
                u = np.clip(np.einsum("ij,ij->i", xy[sel] - a, ab) / L2, 0.0, 1.0)
                proj = a + u[:, None] * ab
                d = np.linalg.norm(xy[sel] - proj, axis=1)
                t = pc.cum[s] + u * np.sqrt(L2)
                better = valid & (d < best_d)
                best_d[better] = d[better]
                best_t[better] = t[better]
            out_t[sel] = best_t
            out_d[sel] = best_d
        return piece_ids, out_t, out_d
