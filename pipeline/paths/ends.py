"""Cutting back path ends that run into other paths.

Where the stripes fork, the paths on either side converge on the fork and the one that
ends there runs on between them or into one's side: on the finer triangles of
:mod:`pipeline.paths.refine` every fork's paths meet in a bare patch a sixteenth of a
triangle across, and on the real tiles four in five of the nodes printed twice lay
within a path width of a path's end. An end is cut back to the first point that keeps
``reach`` path widths from every other path; where two ends crowd each other the
shorter path gives way, so a piece is not cut back from both sides of one gap.
"""

import numpy as np

from pipeline.paths.samples import sample_tree

# Ends crowded closer than this many path widths are cut back: on the coast tile 0.8
# cuts the overlap of the finer triangles' paths to a third (4.6 -> 1.5 %) for a
# seventh of their coverage gain (0.975 -> 0.956), and keeps a margin to both limits
# (0.6: 0.972 / 3.2 %, 0.75: 0.963 / 1.95 %, 0.95: 0.906 / 0.5 %).
REACH = 0.8
# An end is cut back by at most this many path widths (on the real tiles one cut in a
# hundred is longer than 2.3, none longer than 4.4): points further in are not asked.
LONGEST = 4.0
_NEIGHBOURS = 16


def retract_ends(chains, pw, reach=REACH, longest=LONGEST):
    """The open chains with each end cut back while it lies within ``reach * pw`` of
    another path, by at most ``longest * pw``: of two ends crowding each other only the
    shorter path's is cut, and a chain cut back to nothing is left out. Closed chains
    are kept whole.

    chains : list of ((k, 2) points mm, (k - 1, ...) per segment (sigma, or sigma and
    more columns), closed). Returns the same."""
    chains = list(chains)
    if len(chains) < 2:
        return chains
    paths = [np.vstack([p, p[:1]]) if closed else p for p, _, closed in chains]
    samples, label, tree = sample_tree(paths, pw / 4)
    arc, bounds = _arc(samples, label)
    length = arc[bounds[1:] - 1]
    closed = np.array([c for _, _, c in chains], bool)
    to_end = np.where(closed[label], np.inf, np.minimum(arc, length[label] - arc))
    # Only points near an end can be cut, and most ends are cut by less than a width:
    # the points up to a width in are asked first, those further in only for ends cut
    # back all that way.
    end = 2 * label + (arc > length[label] / 2)
    crowded = np.zeros(len(samples), bool)
    ask = np.flatnonzero(to_end <= pw)
    crowded[ask] = _crowded(ask, samples, label, tree, to_end, length, pw, reach)
    through = np.bincount(end[ask], ~crowded[ask], 2 * len(chains)) == 0
    ask = np.flatnonzero((to_end > pw) & (to_end <= longest * pw) & through[end])
    crowded[ask] = _crowded(ask, samples, label, tree, to_end, length, pw, reach)
    kept = _kept_spans(crowded, bounds, closed)
    P = np.concatenate(paths)
    at, pb = _arc(P, np.repeat(np.arange(len(paths)), [len(p) for p in paths]))
    for c, piece in zip(kept[0].tolist(), _cut_spans(P, at, pb, chains, *kept, arc, samples)):
        chains[c] = piece
    return [c for c in chains if c is not None]


def _kept_spans(crowded, bounds, closed):
    """For the open paths with a crowded end (``crowded`` (q,) per sample, the samples of
    path ``c`` from ``bounds[c]`` to ``bounds[c + 1]``), the samples their cut-back part
    runs between: their first and last uncrowded one, or -1 where none is left. Returns
    ((r,) path, (r,) first sample, (r,) last sample), all paths at once."""
    lo, hi = bounds[:-1], bounds[1:]
    c = np.flatnonzero(~closed & (crowded[lo] | crowded[hi - 1]))
    lo, hi = lo[c], hi[c]
    free = np.flatnonzero(~crowded)
    i = np.searchsorted(free, lo)
    a = free[np.minimum(i, len(free) - 1)] if len(free) else np.zeros(len(c), np.int64)
    j = np.searchsorted(free, hi) - 1
    b = free[np.maximum(j, 0)] if len(free) else np.zeros(len(c), np.int64)
    none = (i >= len(free)) | (a >= hi) | (j < 0) | (b < lo) | (b <= a)
    return c, np.where(none, -1, a), np.where(none, -1, b)


def _cut_spans(P, at, pb, chains, which, a, b, arc, samples):
    """:func:`_cut` of each path ``which`` ((r,), points ``P[pb[c]:pb[c + 1]]`` at arc
    lengths ``at``) from sample ``a`` to sample ``b`` (``arc`` along the path, points
    ``samples``), None where ``a`` is -1: the point counts below each end, which
    :func:`_cut` searches for path by path, counted for all at once. Returns a list."""
    size = np.diff(pb)
    start = np.full(len(size), -np.inf)
    stop = np.full(len(size), -np.inf)
    ok = a >= 0
    start[which[ok]], stop[which[ok]] = arc[a[ok]], arc[b[ok]]
    owner = np.repeat(np.arange(len(size)), size)
    upto = np.bincount(owner, at <= np.repeat(start, size), len(size)).astype(np.int64)
    below = np.bincount(owner, at < np.repeat(stop, size), len(size)).astype(np.int64)
    lo = np.maximum(upto, 1)
    hi = np.maximum(np.minimum(below, size - 1), lo - 1)
    out = []
    for c, s, t, x, y in zip(which.tolist(), a.tolist(), b.tolist(), lo[which].tolist(),
                             hi[which].tolist()):
        if s < 0:
            out.append(None)
            continue
        first = pb[c]
        out.append((np.concatenate([samples[s:s + 1], P[first + x:first + y], samples[t:t + 1]]),
                    chains[c][1][x - 1:max(y, x)], False))
    return out


def _crowded(ask, samples, label, tree, to_end, length, pw, reach):
    """Which of the points ``ask`` lie within ``reach * pw`` of another path that does
    not give way to theirs: (len(ask),) bool."""
    if not len(ask):
        return np.zeros(0, bool)
    d, i = tree.query(samples[ask], k=min(_NEIGHBOURS, len(samples)),
                      distance_upper_bound=reach * pw)
    i = np.minimum(i, len(label) - 1)
    mine, theirs = label[ask][:, None], label[i]
    # A neighbour gives way where it is itself near the end of a shorter path.
    firm = ((to_end[i] > pw) | (length[theirs] > length[mine])
            | ((length[theirs] == length[mine]) & (theirs > mine)))
    return ((theirs != mine) & np.isfinite(d) & firm).any(axis=1)


def _arc(points, label):
    """Arc length of each point along its path (points of one path in a row, ``label``
    (q,) sorted), and where each path's points start and end: ((q,), (paths + 1,))."""
    first = np.r_[0, np.flatnonzero(np.diff(label)) + 1]
    bounds = np.r_[first, len(label)]
    step = np.r_[0.0, np.hypot(*np.diff(points, axis=0).T)]
    step[first] = 0.0
    arc = np.cumsum(step)
    return arc - np.repeat(arc[first], np.diff(bounds)), bounds


def _cut(p, at, sg, start, stop, first, last):
    """The part of polyline ``p`` (arc length ``at`` at its points, per segment values
    ``sg``) from arc length ``start`` (point ``first``) to ``stop`` (point ``last``).

    The arc lengths come from other points along the same line, so ``p``'s own ends
    never stand in the middle, however the sums round."""
    lo = max(int(np.searchsorted(at, start, side="right")), 1)
    hi = min(int(np.searchsorted(at, stop, side="left")), len(p) - 1)
    # A part inside one segment (a bridge's piece between two gaps on a segment longer
    # than the piece) is that segment's stretch: two points, the segment's value.
    hi = max(hi, lo - 1)
    return np.vstack([first, p[lo:hi], last]), sg[lo - 1:max(hi, lo)], False
