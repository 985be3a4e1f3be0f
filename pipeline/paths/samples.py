"""Points along the paths and their KD-tree: what every later step of the path plan asks
(which path is near, how far along its own path a point lies) is asked of these."""

import numpy as np
from scipy.spatial import cKDTree


def sample_tree(paths, step):
    """Points along every path at most ``step`` apart (those of :func:`_densify`, all
    paths at once: a loop over thousands of stripe pieces took a second), the path each
    lies on, and a KD-tree of them. Returns ((q, 2), (q,), tree)."""
    paths = [np.asarray(p, float) for p in paths]
    if not paths:
        return np.zeros((0, 2)), np.zeros(0, np.int64), cKDTree(np.zeros((0, 2)))
    P = np.concatenate(paths)
    k = np.array([len(p) for p in paths])
    last = np.cumsum(k) - 1
    # Each point starts the run to the next; a path's last point stands alone.
    d = np.vstack([np.diff(P, axis=0), np.zeros((1, 2))])
    d[last] = 0.0
    n = np.maximum(np.ceil(np.hypot(d[:, 0], d[:, 1]) / step).astype(np.int64), 1)
    seg = np.repeat(np.arange(len(P)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / n[seg]
    # Rows repeated rather than gathered: the same values, in a third of the time.
    samples = np.repeat(P, n, axis=0) + np.repeat(d, n, axis=0) * t[:, None]
    label = np.repeat(np.repeat(np.arange(len(paths)), k), n)
    # An unbalanced tree without compacted nodes: a third of the build time, same answers.
    return samples, label, cKDTree(samples, balanced_tree=False, compact_nodes=False)


def _densify(points, step):
    """Points along a polyline at most ``step`` apart: (q, 2)."""
    d = np.diff(points, axis=0)
    n = np.maximum(np.ceil(np.hypot(d[:, 0], d[:, 1]) / step).astype(int), 1)
    seg = np.repeat(np.arange(len(d)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / n[seg]
    return np.vstack([points[seg] + d[seg] * t[:, None], points[-1:]])


def nearest_other(samples, label, tree, at, reach, k=16, skip=None, known=None):
    """For samples ``at`` ((a,) int), the nearest sample of another path (``label`` (q,)
    the path of each of ``samples``, ``tree`` their KD-tree) within ``reach`` mm, -1
    where none, and its distance (mm, inf where none): (a,), (a,). With ``skip`` ((a,)
    int) that path is passed over too. ``k`` neighbours are asked first; where a path's
    own points crowd (corners closer than the sampling) and fill them all, four times as
    many are asked again. ``known``: those ``k`` of each (:func:`neighbours`) where
    already asked."""
    j = np.full(len(at), -1, np.int64)
    near = np.full(len(at), np.inf)
    ask = np.arange(len(at))
    while len(ask):
        k = min(k, len(samples))
        d, n = known if known is not None else neighbours(samples, tree, at[ask], reach, k)
        known = None
        n = np.minimum(n, len(label) - 1)
        other = (label[n] != label[at[ask]][:, None]) & np.isfinite(d)
        if skip is not None:
            other &= label[n] != skip[ask][:, None]
        has = other.any(axis=1)
        first = np.argmax(other, axis=1)
        rows = np.arange(len(ask))
        near[ask[has]] = d[rows, first][has]
        j[ask[has]] = n[rows, first][has]
        if k == len(samples):
            break
        ask, k = ask[~has & np.isfinite(d[:, -1])], 4 * k
    return j, near


def neighbours(samples, tree, at, reach, k):
    """The ``min(k, q)`` samples nearest each of samples ``at`` ((a,) int) within ``reach``
    mm, nearest first, and their distances (index q, inf past the last): (a, k), (a, k)."""
    k = min(k, len(samples))
    d, n = tree.query(samples[at], k=k, distance_upper_bound=reach)
    return d.reshape(len(at), k), n.reshape(len(at), k)
