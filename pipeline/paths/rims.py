"""Path ends at the sheet's edge joined by leaving out the grazing tail beside them.

Where the paths meet the outline at a slant, neighbouring paths end ``pw / sin(angle)``
apart along it: at a few degrees further than a hop reaches, and a hop along the edge
would print over the next path's last stretch, which runs within a path width of the
edge. That next path passes a path width inward of the first one's end: cut there, its
tail (from the cut to its own end, along the edge all the way) is left out and a U-turn
joins the end to the cut. Two ends fewer, one trace fewer, for a sliver of the edge left
bare: the tail's bead, between the edge and the paths further in.
"""

import numpy as np

from pipeline.paths.ends import _arc, _cut
from pipeline.paths.links import _pieces, merge_joined
from pipeline.paths.stats import sample_tree

# An end is joined to the path beside it that far off (path widths) ...
SPACING = (0.6, 1.4)
# ... whose tail lies within this many path widths of the outline all along.
ALONG_EDGE = 1.0
_NEIGHBOURS = 16


def join_at_rim(chains, pw, boundary, longest):
    """The chains with ends at the edge joined to the path beside them, its tail left out.

    chains : list of ((k, 2) points mm, (k - 1,) sigma, closed), their loose ends those
        no hop joins; pw : path width mm; boundary : the outline's boundary (shapely);
    longest : the longest tail left out, path widths (0: none)

    Returns (the chains, hops (h, 2, 2) mm, the tails left out: list of (k, 2) mm).
    """
    import shapely

    open_ = np.array([not c and len(p) >= 2 for p, _, c in chains], bool)
    if longest <= 0 or open_.sum() < 2:
        return chains, np.zeros((0, 2, 2)), []
    paths = [p for p, _, _ in chains]
    samples, label, tree = sample_tree(paths, pw / 4)
    arc, bounds = _arc(samples, label)
    length = arc[bounds[1:] - 1]
    to_end = np.minimum(arc, length[label] - arc)
    # Only the stretches a tail can span are asked how far they lie from the edge.
    near_end = open_[label] & (to_end <= longest * pw)
    edge = np.full(len(samples), np.inf)
    edge[near_end] = shapely.distance(boundary, shapely.points(samples[near_end]))
    ends = np.flatnonzero(open_[label] & (to_end == 0) & (edge <= ALONG_EDGE * pw))
    found = _beside(samples, label, tree, ends, pw)
    ok = found >= 0
    ends, found = ends[ok], found[ok]
    # The path beside: its nearer end is the tail's, and the tail must hug the edge.
    q = label[found]
    at_start = arc[found] <= length[q] - arc[found]
    tail = np.where(at_start, arc[found], length[q] - arc[found])
    ok = open_[q] & (tail <= longest * pw) & (tail > 0)
    ok &= _hugs(edge, bounds, q, at_start, arc, found, pw)
    ends, found, tail, at_start = ends[ok], found[ok], tail[ok], at_start[ok]
    end_id = 2 * label[ends] + (arc[ends] > 0)
    tail_id = 2 * label[found] + ~at_start
    picked = _picked(end_id, tail_id, tail, length, pw)
    if not picked:
        return chains, np.zeros((0, 2, 2)), []
    chains, tails = _cut_tails(chains, [(int(tail_id[k]), samples[found[k]]) for k in picked])
    joins = np.array([(end_id[k], tail_id[k]) for k in picked], np.int64)
    merged, hops = merge_joined(chains, joins)
    return merged, hops, tails


def _beside(samples, label, tree, at, pw):
    """For samples ``at``, the nearest sample on another path within the spacing
    (-1: none): (a,)."""
    lo, hi = SPACING
    if not len(at):
        return np.zeros(0, np.int64)
    k = min(_NEIGHBOURS, len(samples))
    d, n = tree.query(samples[at], k=k, distance_upper_bound=hi * pw)
    d, n = d.reshape(len(at), k), n.reshape(len(at), k)
    n = np.minimum(n, len(label) - 1)
    other = (label[n] != label[at][:, None]) & np.isfinite(d)
    has = other.any(axis=1)
    first = np.argmax(other, axis=1)
    rows = np.arange(len(at))
    hit = has & (d[rows, first] >= lo * pw)
    return np.where(hit, n[rows, first], -1)


def _hugs(edge, bounds, q, at_start, arc, found, pw):
    """Whether each tail (path ``q``, from its start to sample ``found`` or from there
    to its end) lies within ``ALONG_EDGE`` path widths of the edge all along: (t,)."""
    out = np.empty(len(q), bool)
    for k, (c, start, j) in enumerate(zip(q.tolist(), at_start.tolist(), found.tolist())):
        span = edge[bounds[c]:j + 1] if start else edge[j:bounds[c + 1]]
        out[k] = bool(np.all(span <= ALONG_EDGE * pw))
    return out


def _picked(end_id, tail_id, tail, length, pw):
    """Which candidates to take, shortest tail first: each end joins or loses its tail
    once, a path keeps more than a width between its tails, and no join closes a run of
    paths on itself."""
    parent, root = _pieces(len(length))
    used, cut = set(), np.zeros(len(length))
    picked = []
    for k in np.argsort(tail, kind="stable").tolist():
        e, t = int(end_id[k]), int(tail_id[k])
        a, b = root(e // 2), root(t // 2)
        if e in used or t in used or a == b or cut[t // 2] + tail[k] + pw >= length[t // 2]:
            continue
        parent[b] = a
        used.update((e, t))
        cut[t // 2] += tail[k]
        picked.append(k)
    return picked


def _cut_tails(chains, cuts):
    """The chains with each tail left out: ``cuts`` (end id, the point (2,) mm it now
    ends at). Returns (chains, the tails as (k, 2) mm polylines)."""
    chains = list(chains)
    by_chain = {}
    for e, point in cuts:
        by_chain.setdefault(e // 2, []).append((e % 2, point))
    tails = []
    for c, ends in by_chain.items():
        p, sg, closed = chains[c]
        at = np.r_[0.0, np.cumsum(np.hypot(*np.diff(p, axis=0).T))]
        start, stop = 0.0, at[-1]
        first, last = p[0], p[-1]
        for side, point in ends:
            s = _arc_at(p, at, point)
            if side == 0:
                tails.append(_cut(p, at, sg, 0.0, s, p[0], point)[0])
                start, first = s, point
            else:
                tails.append(_cut(p, at, sg, s, at[-1], point, p[-1])[0])
                stop, last = s, point
        chains[c] = _cut(p, at, sg, start, stop, first, last)
    return chains, tails


def _arc_at(p, at, point):
    """Arc length (mm) along polyline ``p`` of its point nearest ``point``."""
    a, b = p[:-1], p[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", point - a, ab)
                / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18), 0.0, 1.0)
    d = np.linalg.norm(a + t[:, None] * ab - point, axis=1)
    k = int(np.argmin(d))
    return float(at[k] + t[k] * np.sqrt(ab[k] @ ab[k]))


def printed_samples(samples, label, tails, pw):
    """The path samples (``samples`` (q, 2) mm on paths ``label`` (q,)) less those on the
    tails left out, with their KD-tree; paths left out whole are dropped from the
    numbering, so the paths left are numbered 0, 1, ... in the order they were. Other
    paths keep more than half a path width from a tail. Returns ((p, 2), (p,), tree)."""
    from scipy.spatial import cKDTree
    if tails:
        dense, _, _ = sample_tree(tails, pw / 16)
        d, _ = cKDTree(dense).query(samples, distance_upper_bound=pw / 8)
        samples, label = samples[~np.isfinite(d)], label[~np.isfinite(d)]
    label = np.unique(label, return_inverse=True)[1].reshape(-1)
    return samples, label, cKDTree(samples, balanced_tree=False, compact_nodes=False)
