"""Joining open paths end to end by hops.

Stripe paths stop where the stripes fork or the direction field turns over (the
triangle there holds no path) and where they run into the sheet's edge, so a stripe
plan has hundreds of pieces whose ends face another piece's end across the sheet. A
hop is extruded like the paths it joins where it crosses bare sheet; where its centre
line comes within half a path width of another path, or runs back over one of the two
paths it joins away from the end it leaves it at, it would print that bead twice, and
there it moves dry (:mod:`pipeline.paths.dry`). A hop is only taken where that run over
paths stays within a budget and the hop stays on the sheet. Among such hops the
shortest are taken first, each end at most once (a greedy matching), which leaves fewer
loose ends than walking from piece to nearest piece; then augmenting paths join more: a
loose end takes over a join whose other end takes over another, and so on, until one
reaches another loose end. Each end is offered its nearest few ends at first, and only
the ends left loose every end within reach: the long hops are few, and weighing them
all would cost more than the rest of the matching.
"""

import weakref

import numpy as np
from scipy.spatial import cKDTree

from pipeline.paths.samples import sample_tree

# Neighbours looked at per hop sample: enough that the two joined paths' own samples
# (a quarter width apart) cannot hide a third path within half a width.
_CHUNK_POINTS = 100_000
_NEIGHBOURS = 16
# Neighbours asked first: most hop samples find another path, or run out of neighbours
# within half a width, among these (with the spacing's first four, the coast tile's three
# sets of stripes at 175 mm took 6.0 s instead of 6.8, every figure and the G-code the same).
_FIRST = 6
# How many joins deep the search for an augmenting path goes (see :func:`_augment`).
AUGMENT_DEPTH = 8
# A hop leaves a path at its end: the path's samples up to this many path widths along
# it from that end are the hop's own; beyond, a hop within reach of them runs back over
# its own path, which prints it twice as surely as running over a third one.
OWN_END_WIDTHS = 1.0
# The shrink a join's segment carries until :func:`pipeline.paths.dry.finish` gives it
# the mean of its neighbours' and splits it into extruded and dry stretches: unknown, so
# no stage merges it into the segments beside it.
HOP = np.nan


def path_samples(paths, pw):
    """Points along every path at most a quarter path width apart, the path each lies
    on, and a tree of them. ``paths``: list of (k, 2) mm. Returns ((q, 2), (q,), tree)."""
    return sample_tree(paths, pw / 4)


def end_distances(samples, label):
    """Each sample's distance (mm) along its path from the path's first and from its last
    point (``samples``, ``label`` of :func:`path_samples`): (q, 2), read-only.

    The joining of ends, the dry stretches and the hop figures each ask it of the same
    samples: the last answer is kept while those samples live (a stripe set of the
    175 mm dome worked it out three times, 17 ms each)."""
    from pipeline.paths.ends import _arc
    # One read and one write of the slot: a plan in another thread at worst misses.
    last = _LAST_END_DISTANCES[0]
    if last is not None and last[0]() is samples and last[1]() is label:
        return last[2]
    arc, bounds = _arc(samples, label)
    out = np.stack([arc, arc[bounds[1:] - 1][label] - arc], axis=1)
    out.flags.writeable = False
    _LAST_END_DISTANCES[0] = (weakref.ref(samples, _forget_end_distances), weakref.ref(label),
                              out)
    return out


# (samples, label (weak references), their end_distances) of the last call.
_LAST_END_DISTANCES = [None]


def _forget_end_distances(_):
    _LAST_END_DISTANCES[0] = None


def over_others(a, b, end_a, end_b, samples, label, tree, pw, limit=np.inf, from_end=None):
    """For hops from ``a`` to ``b`` ((h, 2) mm) leaving and meeting paths at the ends
    ``end_a`` and ``end_b`` ((h,) int: ``2 c`` the first point of path ``c``, ``2 c + 1``
    its last, -1 none), the length (mm, (h,)) of each whose centre line lies within half
    a path width of another path (``samples``, ``label``, ``tree`` of
    :func:`path_samples`). With ``from_end`` (:func:`end_distances`) the two paths'
    own samples count too where they lie more than ``OWN_END_WIDTHS`` path widths along
    them from the joined end (the hop runs back over its own path). A hop found to run
    over others for more than ``limit`` mm is not measured further: its figure is then
    only some length above ``limit``."""
    hop, bad, seg = over_mask(a, b, end_a, end_b, samples, label, tree, pw, limit, from_end)
    return np.bincount(hop[bad], minlength=len(a)) * seg


def over_mask(a, b, end_a, end_b, samples, label, tree, pw, limit=np.inf, from_end=None):
    """:func:`over_others` point by point: each hop is sampled at ``n`` points (the
    middles of ``n`` equal steps of at most a quarter path width). Returns (the hop of
    each sample (N,) int, hop by hop in order, whether it lies over another path (N,)
    bool, each hop's step (h,) mm)."""
    h = len(a)
    if h == 0:
        return np.zeros(0, np.int64), np.zeros(0, bool), np.zeros(0)
    length = np.linalg.norm(b - a, axis=1)
    n = np.maximum(np.ceil(length / (pw / 4)).astype(np.int64), 1)
    # Thousands of candidate hops on a real tile: their sample points and neighbour
    # lists, all at once, took 600 MB; a chunk at a time keeps the peak small.
    cut = np.searchsorted(np.cumsum(n), np.arange(_CHUNK_POINTS, n.sum(), _CHUNK_POINTS))
    cut = np.unique(cut[(cut > 0) & (cut < h)])
    if len(cut):
        parts = [(p[0], over_mask(a[p], b[p], end_a[p], end_b[p], samples, label, tree, pw,
                                  limit, from_end)) for p in np.split(np.arange(h), cut)]
        return (np.concatenate([first + m[0] for first, m in parts]),
                np.concatenate([m[1] for _, m in parts]), np.concatenate([m[2] for _, m in parts]))
    hop = np.repeat(np.arange(h), n)
    step = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    t = (step + 0.5) / n[hop]
    q = a[hop] + (b - a)[hop] * t[:, None]
    seg = length / n
    bad = np.zeros(len(q), bool)
    asked = np.zeros(len(q), bool)
    count = np.zeros(h, np.int64)
    # Most candidates cross other paths for far longer than the limit: every fourth
    # sample first, then every other, rules most of them out, and only the rest are
    # asked the remaining samples. A sample found within reach of another path's sample
    # at distance delta makes its neighbours closer than reach - delta bad too, unasked.
    for part in (step % 4 == 0, step % 2 == 0, np.ones(len(q), bool)):
        ask = np.flatnonzero(part & ~asked & ~bad & (count * seg <= limit)[hop])
        found, delta = _near_another(q[ask], end_a[hop[ask]], end_b[hop[ask]], label, tree,
                                     0.5 * pw, min(_FIRST, len(samples)),
                                     min(_NEIGHBOURS, len(samples)), from_end,
                                     OWN_END_WIDTHS * pw)
        asked[ask] = True
        bad[ask[found]] = True
        _spread(bad, ask[found], 0.5 * pw - delta[found], seg[hop[ask[found]]], step, n, hop)
        count = np.bincount(hop[bad], minlength=h)
    return hop, bad, seg


def _spread(bad, at, room, seg, step, n, hop):
    """Mark the samples of a hop that lie closer than ``room`` (mm) to the bad samples
    ``at`` (each within reach of another path's sample, by ``room`` less than reach):
    the same path's sample lies within reach of them."""
    # No further than a hop's own samples: a hop of no length has a step of none.
    reach = min(np.ceil((room / np.maximum(seg, 1e-12)).max(initial=0)), n.max(initial=0))
    for j in range(1, int(reach) + 1):
        near = j * seg < room - 1e-9
        if not near.any():
            break
        for sign in (-1, 1):
            k, s = at[near] + sign * j, step[at[near]] + sign * j
            bad[k[(s >= 0) & (s < n[hop[at[near]]])]] = True


def _near_another(q, end_a, end_b, label, tree, reach, k, k_max, from_end=None,
                  own_mm=0.0):
    """Which points ``q`` ((p, 2) mm) lie within ``reach`` of a sample other than their
    own (of the paths whose ends ``end_a`` and ``end_b`` ((p,)) they join, with
    ``from_end`` only those up to ``own_mm`` from that end), or have ``k_max``
    neighbours within it all their own (another could lie beyond them): (p,) bool, and
    the distance to the nearest other sample among those asked ((p,) mm, inf where
    none). The ``k`` nearest are asked first and only points whose ``k`` all lie within
    reach and are their own ask ``k_max``: the nearest other among ``k`` is the nearest
    among ``k_max``, and fewer than ``k`` within reach are all there are (the answer is
    that of asking ``k_max`` of all)."""
    d, i = tree.query(q, k=k, distance_upper_bound=reach)
    d, i = d.reshape(len(q), k), i.reshape(len(q), k)
    near = np.isfinite(d)
    i = np.minimum(i, len(label) - 1)
    lab = label[i]
    other = near
    for end in (end_a, end_b):
        own = lab == (end // 2)[:, None]
        if from_end is not None:
            own &= from_end[i, (end % 2)[:, None]] <= own_mm
        other = other & ~own
    bad = other.any(axis=1)
    delta = np.where(bad, d[np.arange(len(q)), np.argmax(other, axis=1)], np.inf)
    full = near[:, -1] & ~bad
    if k < k_max and full.any():
        bad[full], delta[full] = _near_another(q[full], end_a[full], end_b[full], label, tree,
                                               reach, k_max, k_max, from_end, own_mm)
    else:
        bad |= full
    return bad, delta


def join_ends(chains, pw, max_mm, footprint, samples, label, tree, over_mm=0.0):
    """Pairs of open-path ends to join by a hop: shortest first, each end once.

    chains : list of ((k, 2) points mm, (k - 1,) sigma, closed); ends are numbered
    ``2 c`` (first point of chain ``c``) and ``2 c + 1`` (last point)
    max_mm : longest hop; footprint : prepared shapely polygon the hop stays in
    samples, label, tree : :func:`path_samples` of the chains, labelled by chain
    over_mm : the most a hop may print over paths (:func:`over_others`, its own two
    counted away from their ends)

    Each end is offered its :data:`NEAREST` nearest ends within reach; ends the matching
    leaves loose are then offered every end within reach, and augmenting paths join what
    they can. Returns (j, 2) int, the joined ends.
    """
    open_ = np.array([not closed and len(p) >= 2 for p, _, closed in chains], bool)
    cid = np.flatnonzero(open_)
    if len(cid) < 2:
        return np.zeros((0, 2), np.int64)
    ends = _end_points(chains)[2 * cid[:, None] + np.arange(2)].reshape(-1, 2)
    end_id = (2 * cid[:, None] + np.arange(2)).ravel()
    end_tree = cKDTree(ends)
    k = min(NEAREST + 1, len(ends))
    d, j = end_tree.query(ends, k=k, distance_upper_bound=max_mm)
    i = np.repeat(np.arange(len(ends)), k)
    d, j = d.ravel(), j.ravel()
    first = _pair_keys(i[np.isfinite(d)], j[np.isfinite(d)], len(ends))
    hops = _Hops(chains, ends, end_id, footprint, pw, over_mm, (samples, label, tree))
    hops.add(first)
    joins = _augment(_greedy(*hops.matching), *hops.matching)
    loose = np.flatnonzero(~np.isin(end_id, joins))
    near = end_tree.query_ball_point(ends[loose], max_mm) if len(loose) else []
    i = np.repeat(loose, [len(nb) for nb in near])
    j = np.fromiter((b for nb in near for b in nb), np.int64, count=len(i))
    more = np.setdiff1d(_pair_keys(i, j, len(ends)), first, assume_unique=True)
    if not len(more):
        return joins
    hops.add(more)
    return _augment(joins, *hops.matching)


# Ends each end is offered first (see :func:`join_ends`). Most ends are joined to one
# of their nearest few; offered every end within 40 path widths at once, the matching
# weighed 2.2 times the candidates of 25 widths (197 thousand on a real tile's stripe
# set, 0.43 s against 0.18). Offered their 16 nearest, and the loose ends all within
# reach, it weighs fewer than at 25 and leaves no more ends loose: lower layers, traces
# at 8, 16 and 32 nearest: starfish 2, 1, 1; the real tiles, saddle and elongated peak 1.
NEAREST = 16


def _pair_keys(i, j, n):
    """Unordered pairs ``i - j`` of ``n`` ends, without self pairs or repeats, each as
    one sorted key ``lo * n + hi``: (p,) int."""
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    # Sorted, then the repeats dropped: np.unique's hashing took 50 times as long on
    # these keys (0.24 s for the coast tile's 340 thousand candidate pairs).
    keys = np.sort((lo * n + hi)[lo != hi])
    return keys[np.r_[True, keys[1:] != keys[:-1]]] if len(keys) else keys


class _Hops:
    """The candidate hops between pairs of ``ends`` ((e, 2) mm, numbered ``end_id``) that
    lie on the sheet, as they are added (:meth:`add`): their ends, their cost and the test
    of whether one may be taken (``matching``, the arguments of :func:`_greedy` and
    :func:`_augment`)."""

    def __init__(self, chains, ends, end_id, footprint, pw, over_mm, sampled):
        self.chains, self.ends, self.end_id, self.footprint = chains, ends, end_id, footprint
        self.pw, self.over_mm, self.sampled = pw, over_mm, sampled
        self.from_end = end_distances(*sampled[:2])
        self.outward = _outward(chains)
        self.a = self.b = np.zeros((0, 2))
        self.ea = self.eb = np.zeros(0, np.int64)
        self.length = self.cost = self.known = np.zeros(0)
        self.inside = np.zeros(0, bool)

    def add(self, keys):
        """The hops between the pairs ``keys`` (of :func:`_pair_keys`) added."""
        import shapely
        n = len(self.ends)
        ia, ib = keys // n, keys % n
        ea, eb = self.end_id[ia], self.end_id[ib]
        a, b = self.ends[ia], self.ends[ib]
        mid = (a + b) / 2
        keep = (ea // 2 != eb // 2) & shapely.contains_xy(self.footprint, mid[:, 0], mid[:, 1])
        a, b, ea, eb = a[keep], b[keep], ea[keep], eb[keep]
        length = np.linalg.norm(b - a, axis=1)
        # A turn costs two widths: across a gap, running straight on beats a U-turn.
        cost = length + 2 * self.pw * _turn(self.outward, ea, eb, a, b)
        inside = shapely.contains(self.footprint, shapely.linestrings(np.stack([a, b], axis=1)))
        self.a, self.b = np.concatenate([self.a, a]), np.concatenate([self.b, b])
        self.ea, self.eb = np.concatenate([self.ea, ea]), np.concatenate([self.eb, eb])
        self.length = np.concatenate([self.length, length])
        self.cost = np.concatenate([self.cost, cost])
        self.inside = np.concatenate([self.inside, inside])
        self.known = np.concatenate([self.known, np.full(len(a), np.nan)])

    @property
    def matching(self):
        return self.ea, self.eb, self.cost, self.allowed

    def over(self, k):
        """How far hops ``k`` run over paths (inf where not on the sheet); each hop is
        measured once, whether the greedy matching or the augmenting paths ask first."""
        todo = k[np.isnan(self.known[k])]
        if len(todo):
            mm = over_others(self.a[todo], self.b[todo], self.ea[todo], self.eb[todo],
                             *self.sampled, self.pw, limit=self.over_mm,
                             from_end=self.from_end)
            self.known[todo] = np.where(self.inside[todo], mm, np.inf)
        return self.known[k]

    def allowed(self, k):
        """Which of hops ``k`` may be taken: a hop no longer than the budget runs over no
        more than its length, so only the longer ones are measured."""
        ok = self.inside[k].copy()
        long_ = ok & (self.length[k] > self.over_mm)
        ok[long_] = self.over(k[long_]) <= self.over_mm
        return ok


def _turn(outward, ea, eb, a, b):
    """How far a hop turns away from the paths it joins (``outward`` of
    :func:`_outward`): 0 where it runs straight on from one into the other, 1 where it
    crosses over between two side by side (a U-turn), 2 where it doubles back at both
    ends."""
    h = b - a
    h = h / np.maximum(np.linalg.norm(h, axis=1), 1e-12)[:, None]
    out_a, out_b = outward[ea], outward[eb]
    return (2 - np.einsum("hc,hc->h", out_a, h) + np.einsum("hc,hc->h", out_b, h)) / 2


def _end_points(chains, inner=0):
    """Each chain's first and last point, or with ``inner`` = 1 the points next to
    them (a one-point chain's own): (2 c + 0 or 1, 2) mm, all chains' points gathered
    at once (a stack per chain took 0.03 s a set on the coast tile)."""
    size = np.array([len(p) for p, _, _ in chains])
    first = np.cumsum(size) - size
    last = first + size - 1
    at = np.stack([np.minimum(first + inner, last), np.maximum(last - inner, first)], axis=1)
    return np.concatenate([p for p, _, _ in chains])[at.ravel()]


def _outward(chains):
    """Unit direction in which each path leaves through each end (``2 c`` its first
    point, ``2 c + 1`` its last): (2 c, 2)."""
    d = _end_points(chains) - _end_points(chains, inner=1)
    return d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]


def _greedy(ea, eb, cost, allowed):
    """Cheapest joins first, each end once. A join may close a run of pieces into a ring:
    the ring is then bridged into a path beside it (:mod:`pipeline.paths.bridges`).

    ``allowed(k)`` says which of joins ``k`` may be taken; it is dear (the over-print
    test), so it is asked only of joins whose ends are still free when they come up, a
    batch at a time: most candidates lose an end to a cheaper join first. The answer is
    the one of asking it of every join up front."""
    xs, ys = ea.tolist(), eb.tolist()
    order = np.argsort(cost, kind="stable").tolist()
    used, out = set(), []
    at, batch = 0, 64
    while at < len(order):
        todo = [k for k in order[at:at + batch] if xs[k] not in used and ys[k] not in used]
        at += batch
        batch = min(2 * batch, 4096)
        ok = allowed(np.asarray(todo, np.int64))
        for k, good in zip(todo, ok):
            if good and xs[k] not in used and ys[k] not in used:
                used.update((xs[k], ys[k]))
                out.append((xs[k], ys[k]))
    return np.asarray(out, np.int64).reshape(-1, 2)


def _augment(joins, ea, eb, cost, allowed, depth=AUGMENT_DEPTH):
    """More ends joined than the greedy matching leaves, by augmenting paths.

    From each loose end a breadth-first search alternates a hop not taken and a join
    taken, ``a - b = c - d = ... - z``, until it reaches another loose end ``z``
    (at most ``depth`` joins deep); the path's hops then take the place of its joins:
    one join more, every end still once. The shortest-first order misses these where the
    ends along an edge alternate (a serpentine that one short join in the wrong place
    breaks in two) and all over a real tile, where forks leave ends in clusters: on the
    coast tile the greedy matching left 284 pieces where a maximum matching leaves 72.
    Odd cycles (blossoms) are not followed, so the answer is near a maximum, not one.
    Hops may close runs of pieces into rings, as in :func:`_greedy`: while rings were
    refused (before they were bridged), the real tiles at 175 mm kept 10 and 6 traces a
    layer, the saddle 8 and three islands 8, where now 1, 1, 2 and 2.

    Returns (j, 2) int, the joins."""
    ok = np.flatnonzero(allowed(np.arange(len(ea))))
    ok = ok[np.argsort(cost[ok], kind="stable")]
    adj = _neighbours(ea[ok], eb[ok])
    partner = {}
    for x, y in joins.tolist():
        partner[x], partner[y] = y, x
    for a in sorted(e for e in adj if e not in partner):
        if a in partner:
            continue
        path = _alternating_path(a, adj, partner, depth)
        for x, y in zip(path[0::2], path[1::2]):
            partner[x], partner[y] = y, x
    out = sorted({(min(x, y), max(x, y)) for x, y in partner.items()})
    return np.asarray(out, np.int64).reshape(-1, 2)


def _neighbours(x, y):
    """Each end's neighbours across the hops ``x[i] - y[i]`` (in that order): dict end ->
    list."""
    src, dst = np.stack([x, y], axis=1).ravel(), np.stack([y, x], axis=1).ravel()
    order = np.argsort(src, kind="stable")
    src, dst = src[order], dst[order]
    cut = np.flatnonzero(np.diff(src)) + 1
    keys = src[np.concatenate([[0], cut])] if len(src) else src
    # Slices of one list: an array and a list per end took 0.03 s a set on the coast tile.
    dst, bounds = dst.tolist(), [0] + cut.tolist() + [len(dst)]
    return {k: dst[a:b] for k, a, b in zip(keys.tolist(), bounds[:-1], bounds[1:])}


def _alternating_path(a, adj, partner, depth):
    """The ends ``[a, b, c, d, ..., z]`` of a shortest path from the loose end ``a`` whose
    hops (a, b), (c, d), ... are not taken and whose joins (b, c), ... are, ending at a
    loose end ``z``; [] when none lies within ``depth`` joins."""
    back = {a: None}
    frontier = [a]
    for _ in range(depth + 1):
        nxt = []
        for u in frontier:
            for v in adj.get(u, ()):
                if v in back:
                    continue
                w = partner.get(v)
                if w is None:
                    path = [v, u]
                    while back[path[-1]] is not None:
                        path.append(back[path[-1]])
                    return path[::-1]
                if w in back:
                    continue
                back[v], back[w] = u, v
                nxt.append(w)
        frontier = nxt
        if not frontier:
            break
    return []


def _pieces(n_chains):
    """Which run each piece is in, as pieces are joined: (parent list, root function)."""
    parent = list(range(n_chains))

    def root(c):
        while parent[c] != c:
            parent[c] = parent[parent[c]]
            c = parent[c]
        return c

    return parent, root


def merge_joined(chains, joins, hop=HOP):
    """The chains with the joined ones run together: list of ((k, 2), (k - 1,), closed),
    each hop carrying the shrink ``hop`` (``HOP``: a hop's, settled when the traces are
    finished; None: the mean of the segments either side, for joins printed where a path
    was) (a closed run's last segment is its closing hop), and the hops as (h, 2, 2)
    mm."""
    partner = {}
    for x, y in joins.tolist():
        partner[x], partner[y] = y, x
    seen = np.zeros(len(chains), bool)
    out, hops = [], []
    loose = [c for c in range(len(chains)) if 2 * c not in partner or 2 * c + 1 not in partner]
    for c0 in loose + list(range(len(chains))):
        if seen[c0]:
            continue
        # Enter by a loose end so the walk covers the whole run (any end of a ring).
        end = 2 * c0 if 2 * c0 not in partner or 2 * c0 + 1 in partner else 2 * c0 + 1
        pts, sig, c = [], [], c0
        while True:
            seen[c] = True
            p, s, _ = chains[c]
            if end == 2 * c + 1:                  # entered at the last point: walk back
                p, s = p[::-1], s[::-1]
            if pts:
                hops.append((pts[-1][-1], p[0]))
                sig.append([_mean_end(sig[-1], s) if hop is None else hop])
            pts.append(p)
            sig.append(np.asarray(s, float))
            leave = end ^ 1
            if leave not in partner or seen[partner[leave] // 2]:
                break
            end = partner[leave]
            c = end // 2
        ring = leave in partner                   # back at the first piece
        if ring:
            hops.append((pts[-1][-1], pts[0][0]))
            sig.append([_mean_end(sig[-1], sig[0]) if hop is None else hop])
        out.append((np.vstack(pts), np.concatenate(sig), chains[c0][2] or ring))
    return out, np.asarray(hops, float).reshape(-1, 2, 2)


def _mean_end(before, after):
    """Shrink of a join printed where a path was: the mean of the segments either side
    of it (those known)."""
    ends = [v for v in (before[-1:], after[:1]) if len(v) and np.isfinite(v[0])]
    return float(np.mean(ends)) if ends else HOP
