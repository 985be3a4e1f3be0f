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
    P = np.concatenate(paths)
    at, pb = _arc(P, np.repeat(np.arange(len(paths)), [len(p) for p in paths]))
    for c in np.flatnonzero(~closed).tolist():
        lo, hi = bounds[c], bounds[c + 1]
        if not (crowded[lo] or crowded[hi - 1]):
            continue
        cr = crowded[lo:hi]
        a = lo + int(np.argmax(~cr)) if cr[0] else lo
        b = hi - 1 - int(np.argmax(~cr[::-1])) if cr[-1] else hi - 1
        chains[c] = None if b <= a or cr.all() else _cut(
            P[pb[c]:pb[c + 1]], at[pb[c]:pb[c + 1]], chains[c][1], arc[a], arc[b],
            samples[a], samples[b])
    return [c for c in chains if c is not None]


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
