"""Dry stretches: where a hop runs over printed paths, the nozzle moves on without
extruding.

A hop joins two path ends inside a trace. Extruded, it prints a second bead wherever
its centre line comes within half a path width of another path, or of its own two away
from the ends it joins: on the real tiles at 175 mm about 3 % of the path length,
plastic with nowhere to go that lifts the nozzle and thickens the sheet there. Over
those stretches the nozzle moves at the layer's height without extruding, as slicers
comb travel moves over printed infill: at the travel speed, with no retraction and no
lift, so the trace goes on where it would have. A stretch too short to stop the flow for
stays extruded, and so does a short extruded stretch between two dry ones.

The stages that join paths (:mod:`pipeline.paths.links`, :mod:`pipeline.paths.bridges`,
:mod:`pipeline.paths.rims` and the ordering of traces) mark each join they make with
the shrink :data:`pipeline.paths.links.HOP`: unknown until the traces are finished here,
and never merged into a neighbouring segment on the way.
"""

import numpy as np

from pipeline.paths.links import end_distances, over_mask

# Dry stretches shorter than this many path widths stay extruded (the flow does not
# stop and start again within a few milliseconds), and extruded stretches shorter than
# this between two dry ones go dry.
MIN_DRY_WIDTHS = 2.0
MIN_WET_WIDTHS = 2.0


def finish(traces, tsig, samples, label, tree, pw):
    """The traces with every join (its segment's shrink ``HOP``, NaN) given the mean
    shrink of the segments either side and split into extruded and dry stretches.

    traces : list of (k, 2) mm; tsig : list of (k - 1,) shrink, ``HOP`` at the joins;
    samples, label, tree : points along the printed paths, the path of each and their
    KD-tree (:func:`pipeline.paths.links.path_samples`); pw : path width mm.

    Returns (traces, shrink per segment, dry per segment: list of (k' - 1,) bool, the
    joins as (h, 2, 2) mm, how far each runs over paths (h,) mm, as
    :func:`pipeline.paths.links.over_others` with its own two counted away from their
    ends)."""
    hops, where = _joins(traces, tsig)
    tsig = [_filled(s) for s in tsig]
    dry = [np.zeros(len(s), bool) for s in tsig]
    if not len(hops) or not len(samples):
        return traces, tsig, dry, hops, np.zeros(len(hops))
    hop, over, flag, seg = _dry_samples(hops, samples, label, tree, pw)
    parts = _stretches(hop, flag, len(hops))
    traces, tsig, dry = _split(traces, tsig, dry, hops, where, parts)
    return traces, tsig, dry, hops, np.bincount(hop[over], minlength=len(hops)) * seg


def _joins(traces, tsig):
    """The joins' segments as (h, 2, 2) mm, and where each lies: (h, 2) int (trace,
    segment)."""
    where = [(i, j) for i, s in enumerate(tsig) for j in np.flatnonzero(np.isnan(s)).tolist()]
    where = np.asarray(where, np.int64).reshape(-1, 2)
    hops = np.array([traces[i][j:j + 2] for i, j in where.tolist()], float).reshape(-1, 2, 2)
    return hops, where


def _filled(sigma):
    """``sigma`` with each ``HOP`` the mean of the nearest known values either side."""
    sigma = np.asarray(sigma, float)
    gap = np.isnan(sigma)
    if not gap.any() or gap.all():
        return np.where(gap, 0.0, sigma)
    idx = np.arange(len(sigma))
    before = np.maximum.accumulate(np.where(gap, -1, idx))
    after = np.minimum.accumulate(np.where(gap, len(sigma), idx)[::-1])[::-1]
    lo = sigma[np.maximum(before, 0)]
    hi = sigma[np.minimum(after, len(sigma) - 1)]
    mean = np.where(before < 0, hi, np.where(after >= len(sigma), lo, 0.5 * (lo + hi)))
    return np.where(gap, mean, sigma)


def joined_ends(hops, samples, label, tree):
    """The path ends each hop ((h, 2, 2) mm) leaves and meets: the nearest sample to each
    of its ends, and whichever end of that sample's path lies nearer along it ((h, 2)
    int, ``2 c`` or ``2 c + 1``), with :func:`pipeline.paths.links.end_distances`."""
    from_end = end_distances(samples, label)
    _, at = tree.query(hops.reshape(-1, 2))
    return (2 * label[at] + (from_end[at, 1] < from_end[at, 0])).reshape(-1, 2), from_end


def _dry_samples(hops, samples, label, tree, pw):
    """Each hop's samples (:func:`pipeline.paths.links.over_mask`) and whether each moves
    dry, with the shortest stretches settled: (hop (N,), over another path (N,) bool,
    dry (N,) bool, step (h,) mm)."""
    end, from_end = joined_ends(hops, samples, label, tree)
    hop, over, seg = over_mask(hops[:, 0], hops[:, 1], end[:, 0], end[:, 1], samples, label,
                               tree, pw, from_end=from_end)
    flag = _settle(hop, over, seg, MIN_DRY_WIDTHS * pw, inner=False)
    flag = ~_settle(hop, ~flag, seg, MIN_WET_WIDTHS * pw, inner=True)
    return hop, over, flag, seg


def _settle(hop, flag, seg, shortest, inner):
    """``flag`` ((N,) bool, hop by hop) with its runs shorter than ``shortest`` mm
    cleared; with ``inner`` only those with other runs on both sides of them in the
    same hop."""
    n = len(flag)
    if not n:
        return flag
    start = np.ones(n, bool)
    start[1:] = (hop[1:] != hop[:-1]) | (flag[1:] != flag[:-1])
    run = np.cumsum(start) - 1
    first = np.flatnonzero(start)
    last = np.append(first[1:], n) - 1
    size = (last - first + 1) * seg[hop[first]]
    clear = flag[first] & (size < shortest - 1e-9)
    if inner:
        opens = np.ones(len(first), bool)
        opens[1:] = hop[first[1:]] != hop[first[:-1]]
        closes = np.ones(len(first), bool)
        closes[:-1] = hop[first[1:]] != hop[first[:-1]]
        clear &= ~opens & ~closes
    return flag & ~clear[run]


def _stretches(hop, flag, h):
    """Each hop's stretches as a list of (from, to, dry) fractions of its length, for the
    hops with a dry one: dict hop -> list."""
    n = np.bincount(hop, minlength=h)
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    out = {}
    for k in np.unique(hop[flag]).tolist():
        f = flag[first[k]:first[k] + n[k]]
        cuts = np.flatnonzero(f[1:] != f[:-1]) + 1
        edges = np.concatenate([[0], cuts, [n[k]]]) / n[k]
        out[k] = [(edges[r], edges[r + 1], bool(f[0]) ^ (r % 2 == 1))
                  for r in range(len(edges) - 1)]
    return out


def _split(traces, tsig, dry, hops, where, parts):
    """Split each hop's segment at its stretches' ends (``parts`` of
    :func:`_stretches`); the new segments keep the hop's shrink."""
    traces, tsig, dry = list(traces), list(tsig), list(dry)
    by_trace = {}
    for k in sorted(parts):
        by_trace.setdefault(int(where[k, 0]), []).append(k)
    for i, ks in by_trace.items():
        p, s, d = traces[i], tsig[i], dry[i]
        pts, sig, flags, at = [], [], [], 0
        for k in sorted(ks, key=lambda k: where[k, 1]):
            j = int(where[k, 1])
            a, b = hops[k]
            cuts = np.array([t for t, _, _ in parts[k][1:]])
            pts += [p[at:j + 1], a + (b - a) * cuts[:, None]]
            sig += [s[at:j], np.full(len(parts[k]), s[j])]
            flags += [d[at:j], np.array([w for _, _, w in parts[k]])]
            at = j + 1
        traces[i] = np.vstack(pts + [p[at:]])
        tsig[i] = np.concatenate(sig + [s[at:]])
        dry[i] = np.concatenate(flags + [d[at:]])
    return traces, tsig, dry


def dry_figures(traces, dry):
    """``dry_mm``: the length moved without extruding inside traces, ``dry_stretches``:
    how many times the flow stops for it."""
    mm, count = 0.0, 0
    for p, d in zip(traces, dry):
        if not d.any():
            continue
        step = np.linalg.norm(np.diff(p, axis=0), axis=1)
        mm += float(step[d].sum())
        count += int(np.count_nonzero(d[1:] & ~d[:-1]) + d[0])
    return {"dry_mm": mm, "dry_stretches": count}
