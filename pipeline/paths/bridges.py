"""Closed paths merged into a neighbouring path by a bridge.

A stripe plan's closed paths (rings round a singular point, a hill or an island) have
no end a hop can join: each is entered where a trace happens to pass by, and a ring a
path width from an open path passing it by starts a trace of its own. Where a ring runs
beside another path, a path width of each is left out and two rungs across the gap join
them (the bridge of "connected Fermat spirals", Zhao et al. 2016): the two become one,
no end is added, and the rungs print where the left-out stretches were. A ring bridged
to a ring makes a ring, to an open path an open path; two open paths are never bridged,
which would only trade their ends.
"""

import numpy as np

from pipeline.geometry import polyline_arc
from pipeline.paths.ends import _arc, _cut
from pipeline.paths.links import _pieces, merge_joined
from pipeline.paths.samples import nearest_other, neighbours, sample_tree

# A bridge is laid where the two paths lie this far apart (in path widths) at both
# rungs, a path width apart along the ring; along its neighbour (round a small ring, the
# outer path's stretch is the longer) the rungs lie up to RUN widths apart.
SPACING = (0.7, 1.3)
RUN = 3.0
# Ring samples asked: every fourth (a path width apart), at most so many a ring (the
# 175 mm dome's rings all asked a width apart took 0.8 s against 0.2 and laid the same
# 378 rungs); and the sites kept for each pair of paths side by side.
_EVERY = 4
_PROBES = 64
_PER_PAIR = 8
_APART = 4.0


def bridge_rings(chains, pw):
    """The chains with every closed one bridged to a neighbour where one runs beside it.

    chains : list of ((k, 2) points mm, sigma per segment ((k - 1,); closed, (k,)),
        closed)
    pw : path width, mm

    Returns (the chains, as ``chains``; rungs (r, 2, 2) mm).
    """
    closed = np.array([c for _, _, c in chains], bool)
    if not closed.any() or len(chains) < 2:
        return chains, np.zeros((0, 2, 2))
    paths = [np.vstack([p, p[:1]]) if c else p for p, _, c in chains]
    samples, label, tree = sample_tree(paths, pw / 4)
    arc, bounds = _arc(samples, label)
    sites = _sites(samples, label, tree, arc, bounds, closed, pw)
    cuts = _chosen(sites, closed, arc, bounds, pw)
    if not cuts:
        return chains, np.zeros((0, 2, 2))
    pieces, joins = _cut_apart(chains, paths, cuts)
    merged, rungs = merge_joined(pieces, joins, hop=None)
    return merged, rungs


def _sites(samples, label, tree, arc, bounds, closed, pw):
    """Where a ring could be bridged: for ring samples ``i`` and the sample ``i2`` a path
    width further along, each one's nearest sample on another path (``j``, ``j2``, on
    the same path), both a path width off, their stretch a path width long and away
    from that path's ends. Returns (s, 4) int (i, i2, j, j2), best first."""
    length = arc[bounds[1:] - 1]
    # Along each ring, at most _PROBES samples evenly spaced, at least a width apart.
    size = np.diff(bounds)
    step = np.maximum(_EVERY, size // _PROBES)[label]
    i = np.flatnonzero(closed[label] & ((np.arange(len(label)) - bounds[label]) % step == 0))
    # The sample a path width along the ring, without running past its closing point.
    key = arc + label * (length.max() + 1.0)        # sorted over all paths
    i2 = np.searchsorted(key, key[i] + pw)
    ok = i2 < bounds[label[i] + 1] - 1
    i, i2 = i[ok], i2[ok]
    i, i2, j, j2, dj, dj2 = _beside(samples, label, tree, i, i2, pw)
    lo = SPACING[0]
    ok = (j >= 0) & (j2 >= 0)
    run = np.abs(arc[np.maximum(j2, 0)] - arc[np.maximum(j, 0)])
    ok &= (run > lo * pw) & (run < RUN * pw)
    # Away from the neighbour's ends, where another hop may join it.
    other = label[np.maximum(j, 0)]
    first = np.minimum(arc[np.maximum(j, 0)], arc[np.maximum(j2, 0)])
    last = np.maximum(arc[np.maximum(j, 0)], arc[np.maximum(j2, 0)])
    ok &= closed[other] | ((first > pw) & (last < length[other] - pw))
    i, i2, j, j2 = i[ok], i2[ok], j[ok], j2[ok]
    badness = np.abs(dj[ok] - pw) + np.abs(dj2[ok] - pw) + np.abs(run[ok] - pw)
    # The best few of each pair of paths, a few widths apart along the ring: one is
    # laid, the others stand by where another bridge took its place (round concentric
    # rings the best sites of every pair lie at one angle).
    pair = label[i] * (len(bounds) - 1) + label[j]
    spot = np.floor(arc[i] / (_APART * pw)).astype(np.int64)
    best = _first_of(badness, pair, spot)
    best = best[_rank(badness[best], pair[best]) < _PER_PAIR]
    best = best[np.argsort(badness[best], kind="stable")]
    return np.stack([i, i2, j, j2], axis=1)[best]


def _beside(samples, label, tree, i, i2, pw):
    """The paths beside ring samples ``i`` and ``i2``: for each, its nearest sample on
    another path and the nearest on a third one, unless a path comes closer than
    ``SPACING``. A ring between two others a width off on both sides has one or the
    other nearest by turns along it (the rings round a dome's centre): both are asked, so
    either can be bridged. Returns (i, i2, j, j2, dj, dj2) with each probe twice, ``j``
    and ``j2`` on one path (-1 where ``i2`` has none on it), and their distances."""
    at = np.r_[i, i2]
    reach = SPACING[1] * pw
    # The second path is looked for among the same first neighbours: asked once.
    asked = neighbours(samples, tree, at, reach, 16)
    near, d_near = nearest_other(samples, label, tree, at, reach, known=asked)
    crowded = d_near < SPACING[0] * pw
    near[crowded] = -1
    # Only probes with a path beside them can have a second one.
    ask = np.flatnonzero(near >= 0)
    nxt, d_nxt = np.full(len(at), -1), np.full(len(at), np.inf)
    nxt[ask], d_nxt[ask] = nearest_other(samples, label, tree, at[ask], reach,
                                         skip=label[near[ask]],
                                         known=(asked[0][ask], asked[1][ask]))
    nxt[d_nxt < SPACING[0] * pw] = -1
    n = len(i)
    j, dj = np.r_[near[:n], nxt[:n]], np.r_[d_near[:n], d_nxt[:n]]
    path = np.where(j >= 0, label[np.maximum(j, 0)], -2)
    j2, dj2 = np.full(2 * n, -1), np.full(2 * n, np.inf)
    # At ``i2`` the nearest on that path wins over the next nearest.
    for k, d in ((nxt[n:], d_nxt[n:]), (near[n:], d_near[n:])):
        k, d = np.tile(k, 2), np.tile(d, 2)
        same = (k >= 0) & (label[np.maximum(k, 0)] == path)
        j2[same], dj2[same] = k[same], d[same]
    return np.r_[i, i], np.r_[i2, i2], j, j2, dj, dj2


def _first_of(value, *groups):
    """Index of the least ``value`` in each group of equal ``groups`` keys: (g,)."""
    order = np.lexsort((value, *groups[::-1]))
    if not len(order):
        return order
    keys = np.stack([g[order] for g in groups], axis=1)
    new = np.r_[True, (np.diff(keys, axis=0) != 0).any(axis=1)]
    return order[new]


def _rank(value, group):
    """Each item's rank by ``value`` within its ``group``: (k,)."""
    order = np.lexsort((value, group))
    first = np.r_[0, np.flatnonzero(np.diff(group[order])) + 1]
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order)) - np.repeat(first, np.diff(np.r_[first, len(order)]))
    return rank


def _chosen(sites, closed, arc, bounds, pw):
    """The bridges to lay, best first: each joins two runs of paths not yet one (at most
    one of them open) and keeps a path width clear of the other bridges on either path.
    Returns a list of (path, start mm, stop mm, path, start mm, stop mm, crossed), the
    ring's stretch first; ``crossed``: the neighbour runs the other way."""
    label = np.repeat(np.arange(len(bounds) - 1), np.diff(bounds))
    parent, root = _pieces(len(closed))
    open_ = [not c for c in closed]
    taken = {}
    cuts = []
    for i, i2, j, j2 in sites.tolist():
        a, b = root(int(label[i])), root(int(label[j]))
        if a == b or (open_[a] and open_[b]):
            continue
        ring = (int(label[i]), arc[i], arc[i2])
        crossed = arc[j2] < arc[j]
        other = (int(label[j]), min(arc[j], arc[j2]), max(arc[j], arc[j2]))
        if _clashes(taken, ring, pw) or _clashes(taken, other, pw):
            continue
        for c, s, t in (ring, other):
            taken.setdefault(c, []).append((s, t))
        parent[b] = a
        open_[a] = open_[a] or open_[b]
        cuts.append((*ring, *other, crossed))
    return cuts


def _clashes(taken, cut, pw):
    """Whether ``cut`` (path, start mm, stop mm) comes within ``pw`` of a stretch
    already left out of that path."""
    c, s, t = cut
    return any(s < t0 + pw and t > s0 - pw for s0, t0 in taken.get(c, ()))


def _cut_apart(chains, paths, cuts):
    """The chains cut where bridges leave stretches out, and the rungs as joins between
    the pieces' ends (end ``2 p`` the first point of piece ``p``, ``2 p + 1`` its last).
    Returns (pieces as ``chains``, (r, 2) int)."""
    where = {}
    for n, (c, s, t, c2, s2, t2, crossed) in enumerate(cuts):
        where.setdefault(c, []).append((s, t, n, 0))
        where.setdefault(c2, []).append((s2, t2, n, 1))
    pieces, ends = [], {}
    for c, (p, sg, closed) in enumerate(chains):
        if c not in where:
            pieces.append((p, sg, closed))
            continue
        P = paths[c]
        at = polyline_arc(P)
        gaps = sorted(where[c])
        if closed:
            # Round the ring from the end of its first gap to the start of the same.
            P = np.vstack([P, P[1:]])
            at = np.r_[at, at[1:] + at[-1]]
            sg = np.r_[sg, sg]
            spans = [(gaps[k][1], gaps[(k + 1) % len(gaps)][0]
                      + (at[-1] / 2 if k + 1 == len(gaps) else 0.0), k, (k + 1) % len(gaps))
                     for k in range(len(gaps))]
        else:
            bounds = [(0.0, None)] + [(g[1], k) for k, g in enumerate(gaps)]
            stops = [(g[0], k) for k, g in enumerate(gaps)] + [(at[-1], None)]
            spans = [(b[0], e[0], b[1], e[1]) for b, e in zip(bounds, stops)]
        for start, stop, after, before in spans:
            piece = _cut(P, at, sg, start, stop, _point(P, at, start), _point(P, at, stop))
            if after is not None:
                ends[(gaps[after][2], gaps[after][3], 1)] = 2 * len(pieces)
            if before is not None:
                ends[(gaps[before][2], gaps[before][3], 0)] = 2 * len(pieces) + 1
            pieces.append(piece)
    joins = []
    for n, cut in enumerate(cuts):
        crossed = cut[6]
        # The ring's gap start faces the neighbour's gap start unless it runs the other way.
        joins.append((ends[(n, 0, 0)], ends[(n, 1, int(crossed))]))
        joins.append((ends[(n, 0, 1)], ends[(n, 1, 1 - int(crossed))]))
    return pieces, np.asarray(joins, np.int64).reshape(-1, 2)


def _point(P, at, s):
    """The point at arc length ``s`` (mm) along polyline ``P`` (arc ``at`` at its points)."""
    k = int(np.clip(np.searchsorted(at, s, side="right") - 1, 0, len(P) - 2))
    t = (s - at[k]) / max(at[k + 1] - at[k], 1e-12)
    return P[k] + (P[k + 1] - P[k]) * np.clip(t, 0.0, 1.0)
