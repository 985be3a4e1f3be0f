"""Path ends at the sheet's edge joined by leaving out the grazing tail beside them.

Where the paths meet the outline at a slant, neighbouring paths end ``pw / sin(angle)``
apart along it: at a few degrees further than a hop reaches, and a hop along the edge
would print over the next path's last stretch, which runs within a path width of the
edge. That next path passes a path width inward of the first one's end: cut there, its
tail (from the cut to its own end, along the edge all the way) is left out and a U-turn
joins the end to the cut. Two ends fewer, one trace fewer, for a sliver of the edge left
bare: the tail's bead, between the edge and the paths further in.

A whole path can be such a sliver: where the stripes graze the outline beside a ring
(round a dome, its rings turned apart in the upper layers), a piece a few millimetres
long lies along the edge with rings on its inner side and no end within reach. It is
left out as a tail is, rather than printed as a trace of its own.
"""

import numpy as np

from pipeline.geometry import polyline_arc, polyline_lengths
from pipeline.paths.ends import _arc, _cut
from pipeline.paths.links import _pieces, merge_joined
from pipeline.paths.samples import nearest_other, sample_tree

# An end within AT_EDGE path widths of the outline is joined to the path beside it that
# far off (path widths), whose tail lies within ALONG_EDGE widths of the outline all along
# (it starts a width in, beside the end).
AT_EDGE = 1.0
SPACING = (0.6, 1.4)
ALONG_EDGE = 1.5


def join_at_rim(chains, pw, boundary, longest, printed=None):
    """The chains with ends at the edge joined to the path beside them, its tail left out.

    chains : list of ((k, 2) points mm, (k - 1,) sigma, closed), their loose ends those
        no hop joins; pw : path width mm; boundary : the outline's boundary (shapely);
    longest : the longest tail left out, path widths (0: none); printed : (samples,
        KD-tree) along every path printed, or None: a U-turn whose middle comes within
        a third of a path width of one of them would cross a path, and is not taken

    Returns (the chains, hops (h, 2, 2) mm, the tails left out: list of (k, 2) mm).
    """
    open_ = np.array([not c and len(p) >= 2 for p, _, c in chains], bool)
    if longest <= 0 or open_.sum() < 2:
        return chains, np.zeros((0, 2, 2)), []
    # Only a path's last stretches can be a tail: they alone are sampled, each walked
    # from its end (on a real tile 7 thousand samples instead of 390).
    stretch, end_of = _end_stretches(chains, open_, (longest + 1.0) * pw)
    samples, label, tree = sample_tree(stretch, pw / 4)
    from_end, bounds = _arc(samples, label)
    chain = end_of[label] // 2
    edge = _edge_distance(boundary, samples, pw)
    ends = bounds[:-1][edge[bounds[:-1]] <= AT_EDGE * pw]
    found, off = nearest_other(samples, chain, tree, ends, SPACING[1] * pw)
    found[off < SPACING[0] * pw] = -1
    ends, found = ends[found >= 0], found[found >= 0]
    tail = from_end[found]
    ok = (tail <= longest * pw) & (tail > 0) & _hugs(edge, bounds, label[found], found, pw)
    if printed is not None and ok.any():
        mid = (samples[ends] + samples[found]) / 2
        ok &= ~np.isfinite(printed[1].query(mid, distance_upper_bound=pw / 3)[0])
    ends, found, tail = ends[ok], found[ok], tail[ok]
    end_id, tail_id = end_of[label[ends]], end_of[label[found]]
    length = polyline_lengths([p for p, _, _ in chains])
    picked = _picked(end_id, tail_id, tail, length, pw)
    if not picked:
        return chains, np.zeros((0, 2, 2)), []
    chains, tails = _cut_tails(chains, [(int(tail_id[k]), samples[found[k]]) for k in picked])
    joins = np.array([(end_id[k], tail_id[k]) for k in picked], np.int64)
    merged, hops = merge_joined(chains, joins)
    return merged, hops, tails


def leave_slivers(chains, pw, boundary, longest):
    """The chains less the open ones no longer than ``longest`` path widths that lie
    within ``ALONG_EDGE`` widths of the outline ``boundary`` all along, but for the
    longest chain. Returns (the chains, the slivers left out: list of (k, 2) mm)."""
    length = polyline_lengths([p for p, _, _ in chains])
    short = [c for c, (_, _, closed) in enumerate(chains)
             if not closed and length[c] <= longest * pw and length[c] < length.max()]
    if not short:
        return chains, []
    samples, label, _ = sample_tree([chains[c][0] for c in short], pw / 4)
    off = _edge_distance(boundary, samples, pw) > ALONG_EDGE * pw
    along = np.bincount(label, weights=off, minlength=len(short)) == 0
    drop = {short[k] for k in np.flatnonzero(along).tolist()}
    return ([c for k, c in enumerate(chains) if k not in drop],
            [chains[k][0] for k in sorted(drop)])


def _end_stretches(chains, open_, reach):
    """Each open chain's stretches up to ``reach`` mm from either end, or to its middle
    (a point's tail runs to its nearer end), walked from that end: (list of (k, 2) mm,
    (s,) int the end each starts at, ``2 c`` or ``2 c + 1``)."""
    out, end_of = [], []
    for c in np.flatnonzero(open_).tolist():
        p = chains[c][0]
        for side, q in ((0, p), (1, p[::-1])):
            at = polyline_arc(q)
            k = max(int(np.searchsorted(at, min(reach, at[-1] / 2))), 1)
            out.append(q[:k + 1])
            end_of.append(2 * c + side)
    return out, np.asarray(end_of, np.int64)


def _edge_distance(boundary, points, pw):
    """Distance (mm) from each of ``points`` to the outline ``boundary``, to within an
    eighth of a path width: (p,)."""
    import shapely
    from scipy.spatial import cKDTree
    dense = shapely.get_coordinates(shapely.segmentize(boundary, pw / 4))
    return cKDTree(dense).query(points)[0]


def _hugs(edge, bounds, stretch, found, pw):
    """Whether each tail (stretch ``stretch`` from its end to sample ``found``) lies
    within ``ALONG_EDGE`` path widths of the edge all along: (t,) bool."""
    out = np.empty(len(found), bool)
    for k, (c, j) in enumerate(zip(stretch.tolist(), found.tolist())):
        out[k] = bool(np.all(edge[bounds[c]:j + 1] <= ALONG_EDGE * pw))
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
        at = polyline_arc(p)
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


def printed_samples(samples, label, tree, tails, pw):
    """The path samples (``samples`` (q, 2) mm on paths ``label`` (q,), their KD-tree
    ``tree``) less those on the tails left out, with a KD-tree of their own; paths left
    out whole are dropped from the numbering, so the paths left are numbered 0, 1, ...
    in the order they were. Other paths keep more than half a path width from a tail.
    Returns ((p, 2), (p,), tree)."""
    from scipy.spatial import cKDTree
    if not tails:
        return samples, label, tree
    dense, _, _ = sample_tree(tails, pw / 16)
    near = tree.query_ball_point(dense, pw / 8, return_sorted=False)
    keep = np.ones(len(samples), bool)
    keep[np.concatenate([np.asarray(n, np.int64) for n in near])] = False
    samples, label = samples[keep], np.unique(label[keep], return_inverse=True)[1].reshape(-1)
    return samples, label, cKDTree(samples, balanced_tree=False, compact_nodes=False)
