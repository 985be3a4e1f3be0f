"""Arc fitting for G-code: replace runs of short chords by G2/G3 arcs.

A run of polyline points that lie on one circle (within a tolerance) becomes
one arc move. The arc must stay within ``tolerance_mm`` of the original
polyline everywhere: the points' radial deviation plus the chord sagitta
(how far the arc bulges away from each chord) plus the G-code rounding of the
centre must fit in the budget. Arcs never cross a thickness jump: the
per-segment values (sigma or thickness) over one arc may span at most
``max_value_span``.

Candidates come from the circumcircle of every consecutive point triple
(vectorised); consecutive triples whose circles agree form runs, and each run
is verified (and split in halves where it fails) with a Python loop over runs,
not over points.
"""

import numpy as np

# Arcs sweeping more than this are split: a near-full circle makes the G-code
# centre/end ambiguous to some firmware, and half circles lose nothing.
MAX_SWEEP_RAD = np.pi
# Below this many chords an arc saves too little to be worth its I/J bytes.
MIN_SEGMENTS = 3
# Nearly straight runs are left to G1: their centres are far away and
# ill-conditioned after rounding, and upstream merging already joined them.
MAX_RADIUS_MM = 2000.0
# Centre coordinates (I, J) are written with 3 decimals.
ROUNDING_MM = 0.5e-3 * np.sqrt(2)


def circumcircles(a, b, c):
    """Circles through point triples.

    Parameters
    ----------
    a, b, c : (n, 2) float, mm

    Returns
    -------
    centre : (n, 2) float, mm (NaN where collinear)
    radius : (n,) float, mm (inf where collinear)
    turn : (n,) float, sign of the turn a->b->c (+1 counter-clockwise)
    """
    ab = b - a
    ac = c - a
    cross = ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0]
    d = 2.0 * cross
    ab2 = np.einsum("ij,ij->i", ab, ab)
    ac2 = np.einsum("ij,ij->i", ac, ac)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (ac[:, 1] * ab2 - ab[:, 1] * ac2) / d
        uy = (ab[:, 0] * ac2 - ac[:, 0] * ab2) / d
    centre = a + np.stack([ux, uy], axis=1)
    radius = np.hypot(ux, uy)
    bad = ~np.isfinite(radius) | (np.abs(cross) < 1e-12)
    centre[bad] = np.nan
    radius[bad] = np.inf
    return centre, radius, np.sign(cross)


def _runs(mask):
    """Start/stop (exclusive) index pairs of True runs in a 1-D bool array."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def _check_arc(points, i, j, tol):
    """Circle through points i..j (inclusive) if it passes, else None.

    Returns ``(centre, radius, ccw, sweep_rad)``.
    """
    p = points[i:j + 1]
    m = (i + j) // 2
    c, r, turn = circumcircles(points[i:i + 1], points[m:m + 1], points[j:j + 1])
    r = float(r[0])
    if not np.isfinite(r) or r > MAX_RADIUS_MM:
        return None
    c = c[0]
    d = p - c
    dev = np.abs(np.hypot(d[:, 0], d[:, 1]) - r)
    ang = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    step = np.diff(ang)
    ccw = turn[0] > 0
    if ccw and not np.all(step > 0) or (not ccw) and not np.all(step < 0):
        return None
    sweep = abs(ang[-1] - ang[0])
    if sweep > MAX_SWEEP_RAD:
        return None
    # Sagitta of the arc over each chord: how far the arc leaves the polyline.
    sagitta = r * (1.0 - np.cos(np.abs(step) / 2.0))
    if dev.max() + sagitta.max() + ROUNDING_MM > tol:
        return None
    return c, r, bool(ccw), float(sweep)


def _fits(points, values, i, j, tol, span):
    v = values[i:j]
    if v.max() - v.min() > span:
        return None
    return _check_arc(points, i, j, tol)


def _greedy(points, values, lo, hi, tol, span):
    """Longest arcs from left to right over points lo..hi (inclusive).

    Gallops (doubling the span) then bisects for the farthest end that still
    fits, so a run of n points costs O(n log n) work in O(arcs log n) checks.
    """
    out = []
    i = lo
    while hi - i >= MIN_SEGMENTS:
        j = i + MIN_SEGMENTS
        fit = _fits(points, values, i, j, tol, span)
        if fit is None:
            i += 1
            continue
        good, step = j, MIN_SEGMENTS
        bad = None
        while True:
            j = min(good + step, hi)
            if j == good:
                break
            f = _fits(points, values, i, j, tol, span)
            if f is None:
                bad = j
                break
            good, fit = j, f
            step *= 2
        if bad is not None:
            while bad - good > 1:
                m = (good + bad) // 2
                f = _fits(points, values, i, m, tol, span)
                if f is None:
                    bad = m
                else:
                    good, fit = m, f
        out.append((i, good, fit))
        i = good
    return out


def fit_arcs(points, values, tolerance_mm, max_value_span):
    """Group a polyline's segments into arcs and lines.

    Parameters
    ----------
    points : (k, 2) float, mm
        Polyline vertices (one trace).
    values : (k - 1,) float
        Per-segment value that must not jump inside an arc (sigma or theta).
    tolerance_mm : float
        Largest distance allowed between the arc and the polyline.
    max_value_span : float
        Largest max-min of ``values`` over one arc.

    Returns
    -------
    ends : (q,) int
        Index of each move's end point in ``points`` (increasing; last k-1).
    centre : (q, 2) float, mm
        Arc centre per move, NaN for straight moves.
    ccw : (q,) bool
        Counter-clockwise arc (G3); False for G2 or lines.
    """
    points = np.asarray(points, dtype=float)
    values = np.asarray(values, dtype=float)
    k = len(points)
    all_lines = (np.arange(1, k), np.full((k - 1, 2), np.nan), np.zeros(k - 1, bool))
    if k < MIN_SEGMENTS + 1 or tolerance_mm <= 0:
        return all_lines
    _, r, turn = circumcircles(points[:-2], points[1:-1], points[2:])
    # Triple t spans points t..t+2. Neighbouring triples are arc candidates when
    # they turn the same way; their own circles are too noisy to compare (short
    # chords, 1 um rounding), so every arc is verified on its whole span.
    ok = np.isfinite(r) & (r < MAX_RADIUS_MM)
    dv = np.abs(np.diff(values))
    agree = (ok[1:] & ok[:-1] & (turn[1:] == turn[:-1])
             & (np.maximum(dv[:-1], dv[1:]) <= max_value_span))
    # Runs of agreeing triple pairs t..u cover points t..u+2.
    starts, stops = _runs(agree)
    arcs = []
    for s, e in zip(starts.tolist(), stops.tolist()):
        arcs.extend(_greedy(points, values, s, e + 2, tolerance_mm, max_value_span))
    if not arcs:
        return all_lines
    arcs.sort(key=lambda a: a[0])
    ends, centres, ccws = [], [], []
    pos = 0
    for i, j, (cen, _, ccw, _) in arcs:
        if i < pos:
            continue
        ends.extend(range(pos + 1, i + 1))
        centres.extend([(np.nan, np.nan)] * (i - pos))
        ccws.extend([False] * (i - pos))
        ends.append(j)
        centres.append(tuple(cen))
        ccws.append(ccw)
        pos = j
    ends.extend(range(pos + 1, k))
    centres.extend([(np.nan, np.nan)] * (k - 1 - pos))
    ccws.extend([False] * (k - 1 - pos))
    return (np.asarray(ends, dtype=np.int64), np.asarray(centres, dtype=float).reshape(-1, 2),
            np.asarray(ccws, dtype=bool))


def moves_with_arcs(q, starts, th_um, arc_vals, tolerance_mm, arc_span, flow=None):
    """Per-move arrays for a set of traces, arcs where they fit.

    ``q`` (n, 2) int um points, ``starts`` (t+1,) trace offsets, ``th_um``
    (n - t, K) int um thickness per segment in each of K layer groups, ``arc_vals``
    per-segment values an arc may not span by more than ``arc_span``, ``flow``
    (n - t,) 1 where a segment extrudes and 0 where it moves dry (default all 1): no
    arc spans a change of it.

    Returns dict of: ``end`` (m,2) int um, ``kind`` (m,) int8 (1 line, 2 cw, 3 ccw),
    ``ij`` (m,2) int um, ``th`` (m, K) int um, ``len`` (m,) float mm, ``flow`` (m,),
    ``first`` (t,) int index of each trace's first move, ``start`` (t,2) int um.
    """
    t = len(starts) - 1
    seg_starts = starts[:-1] - np.arange(t)  # segments of trace i: seg_starts[i]:...+k_i-1
    flow = np.ones(len(th_um)) if flow is None else np.asarray(flow, float)
    if tolerance_mm <= 0:
        seg_mask = np.ones(len(q), bool)
        seg_mask[starts[:-1]] = False
        end = q[seg_mask]
        d = (q[1:] - q[:-1])[seg_mask[1:]] / 1000.0
        return {"end": end, "kind": np.ones(len(end), np.int8), "ij": np.zeros_like(end),
                "th": th_um, "len": np.hypot(d[:, 0], d[:, 1]), "flow": flow,
                "first": seg_starts, "start": q[starts[:-1]]}
    ends, kinds, ijs, ths, lens, flows, firsts = [], [], [], [], [], [], []
    n_moves = 0
    for i in range(t):
        a, b = starts[i], starts[i + 1]
        pq = q[a:b]
        p = pq / 1000.0
        s0 = seg_starts[i]
        th = th_um[s0:s0 + (b - a - 1)]
        vals = arc_vals[s0:s0 + (b - a - 1)]
        fl = flow[s0:s0 + (b - a - 1)]
        e_idx, centre, ccw = _fit_by_flow(p, vals, fl, tolerance_mm, arc_span)
        prev = np.concatenate([[0], e_idx[:-1]])
        nseg = e_idx - prev
        is_arc = np.isfinite(centre[:, 0])
        d = pq[1:] - pq[:-1]
        seg_len = np.hypot(d[:, 0], d[:, 1]) / 1000.0
        cum = np.concatenate([[0.0], np.cumsum(seg_len)])
        cum_th = np.concatenate([np.zeros((1, th.shape[1])),
                                 np.cumsum(seg_len[:, None] * th, axis=0)])
        # An arc prints at its chords' length-weighted mean thickness (same volume).
        mean_th = ((cum_th[e_idx] - cum_th[prev])
                   / np.maximum(cum[e_idx] - cum[prev], 1e-12)[:, None])
        mth = np.where((nseg > 1)[:, None], np.rint(mean_th), th[e_idx - 1]).astype(np.int64)
        ij = np.zeros((len(e_idx), 2), np.int64)
        ij[is_arc] = np.rint(centre[is_arc] * 1000.0).astype(np.int64) - pq[prev[is_arc]]
        ln = cum[e_idx] - cum[prev]
        if is_arc.any():
            ln[is_arc] = arc_length(pq[prev[is_arc]], pq[e_idx[is_arc]], ij[is_arc],
                                     ccw[is_arc])
        kind = np.where(is_arc, np.where(ccw, 3, 2), 1).astype(np.int8)
        ends.append(pq[e_idx])
        kinds.append(kind)
        ijs.append(ij)
        ths.append(mth)
        lens.append(ln)
        flows.append(fl[e_idx - 1])
        firsts.append(n_moves)
        n_moves += len(e_idx)
    return {"end": np.concatenate(ends), "kind": np.concatenate(kinds),
            "ij": np.concatenate(ijs), "th": np.concatenate(ths), "len": np.concatenate(lens),
            "flow": np.concatenate(flows), "first": np.asarray(firsts, np.int64),
            "start": q[starts[:-1]]}


def _fit_by_flow(points, values, flow, tolerance_mm, arc_span):
    """:func:`fit_arcs` of one trace, each run of segments of one ``flow`` alone."""
    cut = np.flatnonzero(flow[1:] != flow[:-1]) + 1
    if not len(cut):
        return fit_arcs(points, values, tolerance_mm, arc_span)
    bounds = np.concatenate([[0], cut, [len(flow)]])
    parts = [(lo, fit_arcs(points[lo:hi + 1], values[lo:hi], tolerance_mm, arc_span))
             for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist())]
    return (np.concatenate([lo + e for lo, (e, _, _) in parts]),
            np.concatenate([c for _, (_, c, _) in parts]),
            np.concatenate([w for _, (_, _, w) in parts]))


def arc_length(start_um, end_um, ij_um, ccw):
    """XY length of G2/G3 arcs as firmware runs them (radius from the start point)."""
    c = start_um + ij_um
    a0 = np.arctan2(start_um[:, 1] - c[:, 1], start_um[:, 0] - c[:, 0])
    a1 = np.arctan2(end_um[:, 1] - c[:, 1], end_um[:, 0] - c[:, 0])
    sweep = np.where(ccw, a1 - a0, a0 - a1) % (2 * np.pi)
    sweep[sweep < 1e-9] = 2 * np.pi
    return np.hypot(ij_um[:, 0], ij_um[:, 1]) / 1000.0 * sweep
