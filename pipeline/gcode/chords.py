"""Chord merging: fewer, longer G1 moves within a distance tolerance of the tool path.

A printer fed over a serial link executes at most as many moves per second as the
link carries lines; tool paths sampled finely (a point every few tenths of a
millimetre) ask for more at print speed. Douglas-Peucker simplification (GEOS,
vectorised over all runs at once) keeps every point of a path that lies farther
than ``tolerance_mm`` from the merged chord, so the printed line never leaves the
planned one by more than the tolerance.

A merged move prints one thickness, so chords never merge across a change in the
per-segment values (shrink, bilayer difference): segments are cut into runs whose
values share one bucket of width ``value_step``, and each run is simplified alone.
"""

import numpy as np
import shapely


def merge_chords(traces, values, tolerance_mm, value_step):
    """Merge consecutive chords of every trace.

    Parameters
    ----------
    traces : list of (k_i, 2) float, mm
    values : list of (k_i - 1, m) float
        Per-segment values (shrink, ...) a merged move must not mix beyond one bucket.
    tolerance_mm : float
        Largest distance of a removed point from the merged chord; 0 keeps all.
    value_step : float
        Bucket width of the values (e.g. the profile's ``merge_sigma``).

    Returns
    -------
    traces, values : lists as given, with each merged segment's value the mean of
    the segments it replaces.
    """
    if tolerance_mm <= 0 or not traces:
        return traces, values
    pts = np.concatenate(traces)
    n_pts = np.array([len(t) for t in traces])
    trace_of_pt = np.repeat(np.arange(len(traces)), n_pts)
    vals = np.concatenate([np.asarray(v, float).reshape(len(t) - 1, -1)
                           for t, v in zip(traces, values)])
    seg_start = np.flatnonzero(np.diff(trace_of_pt) == 0)       # global point index
    keep = _kept_points(pts, seg_start, vals, tolerance_mm, value_step)
    return _rebuild(pts, trace_of_pt, keep, vals, n_pts)


def _kept_points(pts, seg_start, vals, tolerance_mm, value_step):
    """Sorted global indices of the points Douglas-Peucker keeps, run by run."""
    if len(seg_start) == 0:
        return np.arange(len(pts))
    bucket = np.floor(vals / max(value_step, 1e-12)).astype(np.int64)
    new_run = np.ones(len(seg_start), bool)
    new_run[1:] = (seg_start[1:] != seg_start[:-1] + 1) | (bucket[1:] != bucket[:-1]).any(axis=1)
    run = np.cumsum(new_run) - 1
    first = np.flatnonzero(new_run)
    n_seg = np.diff(np.append(first, len(seg_start)))
    # A run of s segments owns s + 1 points: its segments' starts and the last end.
    run_pts = np.concatenate([seg_start, seg_start[first + n_seg - 1] + 1])
    run_ids = np.concatenate([run, np.arange(len(first))])
    order = np.lexsort((run_pts, run_ids))
    coords = np.column_stack([pts[run_pts[order]], run_pts[order].astype(float)])
    lines = shapely.linestrings(coords, indices=run_ids[order])
    simple = shapely.simplify(lines, tolerance_mm, preserve_topology=False)
    kept = np.ones(len(pts), bool)
    kept[run_pts] = False                                       # one-point traces stay
    kept[np.rint(shapely.get_coordinates(simple, include_z=True)[:, 2]).astype(np.int64)] = True
    return np.flatnonzero(kept)


def _rebuild(pts, trace_of_pt, keep, vals, n_pts):
    """Traces of the kept points and each new segment's mean value."""
    trace = trace_of_pt[keep]
    seg_of_pt = np.arange(len(pts)) - trace_of_pt               # segments before the point
    same = trace[1:] == trace[:-1]
    a = seg_of_pt[keep[:-1]][same]
    b = seg_of_pt[keep[1:]][same]
    csum = np.vstack([np.zeros((1, vals.shape[1])), np.cumsum(vals, axis=0)])
    merged = (csum[b] - csum[a]) / (b - a)[:, None]
    cut_pts = np.cumsum(np.bincount(trace, minlength=len(n_pts)))[:-1]
    new_traces = np.split(pts[keep], cut_pts)
    cut_segs = np.cumsum(np.maximum(np.bincount(trace, minlength=len(n_pts)) - 1, 0))[:-1]
    new_vals = np.split(merged, cut_segs)
    return new_traces, new_vals
