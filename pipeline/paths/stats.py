"""Figures of a tool-path plan: the report's ``toolpath`` section.

Spacing (from points on each path to the nearest other path), coverage and
overlap of the flat footprint (within half a path width of one path, or of
two), sharp turns inside traces, and how far the paths turn away from the
isolines they should follow (the shrink acts along the path).
"""

import functools

import numpy as np

from pipeline.geometry import hat_gradients
from pipeline.paths.dry import joined_ends
from pipeline.paths.links import over_others
from pipeline.paths.samples import sample_tree


def path_metrics(traces, tsig, raw, xy, faces, level, u, poly, pw, hops=None, samples=None,
                 hop_over=None):
    """The report's ``toolpath`` section.

    Parameters
    ----------
    traces : list of (k, 2) float, mm; tsig : list of (k - 1,) float
    raw : list of ((k, 2) float, closed bool), the loops and arcs before chaining
    xy : (n, 2) float, mm, flat layout; faces : (m, 3) int
    level, u : (n,) float, isoline value and path index per vertex (None: paths not
        from isolines, no ``isoline_angle_deg``)
    poly : shapely polygon, the flat outline; pw : float, path width mm
    hops : (h, 2, 2) float, mm, the joins between the paths of ``raw`` inside the
        traces (None: not known, no ``hop_mm``); hop_over : how far each runs over
        paths, (h,) mm, where that is known (:func:`hop_figures`)
    samples : (points, path of each, KD-tree) along ``raw`` a quarter width apart, as
        :func:`pipeline.paths.links.path_samples` gives them (None: made here)
    """
    seg_count = sum(len(s) for s in tsig)
    length = 0.0
    sharp = 0
    for p in traces:
        d = np.diff(p, axis=0)
        length += float(np.hypot(d[:, 0], d[:, 1]).sum())
        if len(d) > 1:
            cosang = np.einsum("ij,ij->i", d[:-1], d[1:]) / np.maximum(
                np.linalg.norm(d[:-1], axis=1) * np.linalg.norm(d[1:], axis=1), 1e-12)
            sharp += int((cosang < 0).sum())
    # Spacing: from points on each path to the nearest point of another path.
    if samples is None:
        samples = sample_tree([p for p, _ in raw], pw / 4)
    samples, label, tree = samples
    # Every twelfth sample (three path widths apart along a path): on the real tiles at
    # 175 mm the percentiles are those of every sixth within 0.001 mm, in half the time
    # (every sixth was every third's within 0.0003 mm).
    probe = np.arange(0, len(samples), 12)
    spacing = _to_another(samples[probe], label[probe], label, tree, 3 * pw,
                          min(14, len(samples)))
    covered, twice = coverage_grid(samples, label, xy, poly, pw)
    hop = {} if hops is None else hop_figures(hops, samples, label, tree, pw, hop_over)
    pct = np.percentile(spacing, [5, 50, 95]) if len(spacing) else [np.nan] * 3
    return {"traces": len(traces), "segments": int(seg_count), "length_mm": length,
            "travel_moves": max(len(traces) - 1, 0), "sharp_turns": sharp,
            "spacing_mm": {"target": pw, "p05": float(pct[0]), "p50": float(pct[1]),
                           "p95": float(pct[2])},
            "coverage": float(covered.mean()) if len(covered) else 0.0,
            "overlap": float(twice.mean()) if len(covered) else 0.0,
            "loops_and_arcs": len(raw), "ends_inside": _ends_inside(traces, poly, pw), **hop,
            **({} if level is None else {"isoline_angle_deg": dict(zip(("p50", "p95"), (
                _weighted_percentiles(*isoline_angles(xy, faces, level, u), [50, 95]))))})}


def _ends_inside(traces, poly, pw):
    """Trace ends farther than a path width from the outline ``poly``: where stripes
    fork or the field has a singular point, a path ends between others, joined only by a
    hop that prints over other paths; the traces can be no fewer than half the ends
    left (a closed trace has none)."""
    import shapely
    ends = [p[[0, -1]] for p in traces
            if len(p) > 1 and not np.allclose(p[0], p[-1], atol=1e-9)]
    if not ends or poly is None:
        return 0
    far = shapely.distance(poly.boundary, shapely.points(np.concatenate(ends))) > pw
    return int(np.count_nonzero(far))


def _to_another(points, own, label, tree, reach, k):
    """Distance from each point (on path ``own``) to the nearest sample of another path
    within ``reach``, among its ``k`` nearest: (found,) mm for the points that find one.
    Samples a quarter width apart put about nine of a point's own within a width of it,
    so fewer than ``k`` leave the next path out (asking four first and the rest again
    found another path for one point in forty thousand on a real tile)."""
    d, i = tree.query(points, k=k, distance_upper_bound=reach)
    d, i = d.reshape(len(points), k), i.reshape(len(points), k)
    other = (label[np.minimum(i, len(label) - 1)] != own[:, None]) & np.isfinite(d)
    has = other.any(axis=1)
    return d[has, np.argmax(other[has], axis=1)]


def hop_figures(hops, samples, label, tree, pw, every=None):
    """``hop_mm``: the length of the hops that join paths inside traces,
    ``hop_overprint_mm``: how much of it runs over a third path (its centre line within
    half a path width of a path other than the two it joins), and
    ``hop_overprint_own_mm``: how much more runs back over its own two paths, away from
    the ends it joins them at (:data:`pipeline.paths.links.OWN_END_WIDTHS`); coverage
    and overlap, taken over the paths alone, see neither. Most of what runs over paths
    moves dry (:mod:`pipeline.paths.dry`: ``dry_mm``).

    hops : (h, 2, 2) mm; samples, label, tree : points along the paths, the path of each
    and their KD-tree; every : how far each hop runs over paths, its own two counted
    (:func:`pipeline.paths.links.over_others` with ``from_end``), where already known."""
    hops = np.asarray(hops, float).reshape(-1, 2, 2)
    if not len(hops):
        return {"hop_mm": 0.0, "hop_overprint_mm": 0.0, "hop_overprint_own_mm": 0.0}
    end, from_end = joined_ends(hops, samples, label, tree)
    if every is None:
        every = over_others(hops[:, 0], hops[:, 1], end[:, 0], end[:, 1], samples, label,
                            tree, pw, from_end=from_end)
    # Over a third path is part of that: only the hops over some path are asked again.
    over = np.flatnonzero(every > 0)
    third = np.zeros(len(hops))
    third[over] = over_others(hops[over, 0], hops[over, 1], end[over, 0], end[over, 1],
                              samples, label, tree, pw)
    return {"hop_mm": float(np.linalg.norm(hops[:, 1] - hops[:, 0], axis=1).sum()),
            "hop_overprint_mm": float(third.sum()),
            "hop_overprint_own_mm": float((every - third).sum())}


def coverage_grid(samples, label, xy, poly, pw):
    """Which points of a grid over the flat footprint the paths cover.

    The grid has a node every ``pw / 2.5`` mm over the bounding box of ``xy``
    ((n, 2) mm), kept where it lies inside ``poly`` (the flat outline). A node
    is covered when a path sample (``samples`` (q, 2) mm, on path ``label``
    (q,) int) lies within half a path width of it, and covered twice when
    samples of two different paths lie within 0.999 of that.

    Returns
    -------
    covered, twice : (g,) bool, one per grid node inside the outline
    """
    res = pw / 2.5
    r = pw / 2
    x0, y0 = xy.min(axis=0)
    x1, y1 = xy.max(axis=0)
    gx = np.arange(x0, x1, res) + res / 2
    gy = np.arange(y0, y1, res) + res / 2
    nx, ny = len(gx), len(gy)
    inside = _inside_grid(poly, gx, gy)
    covered = np.zeros(nx * ny, dtype=bool)
    twice = np.zeros(nx * ny, dtype=bool)
    if len(samples) == 0 or nx == 0 or ny == 0:
        return covered[inside], twice[inside]
    # Any one path's label per node, set as the samples stamp it (the nodes and labels of
    # all samples at once were 25 MB on the 175 mm dome).
    owner = np.full(nx * ny, -1, dtype=np.int32)
    # In chunks of samples: the per-offset arrays of all samples at once would be
    # the plan's peak memory (70 MB on the 175 mm dome).
    for lo in range(0, len(samples), _STAMP_CHUNK):
        sl = slice(lo, lo + _STAMP_CHUNK)
        _stamp(samples[sl], label[sl], gx, gy, res, r, covered, owner, twice)
    return covered[inside], twice[inside]


def _inside_grid(poly, gx, gy, rows=64):
    """Which nodes of the grid ``gx`` (nx,) by ``gy`` (ny,) mm lie inside ``poly``:
    (nx * ny,) bool, row-major, read-only.

    A plan's stripe sets share the outline and the path width, so the grid is tested
    once for all three (0.11 s a set on the 175 mm dome)."""
    return _inside_axes(poly, gx.tobytes(), gy.tobytes(), rows)


@functools.lru_cache(maxsize=4)
def _inside_axes(poly, gx, gy, rows):
    """:func:`_inside_grid` of the axes as bytes (hashable, compared exactly). A band of
    ``rows`` grid rows at a time, so the nodes' coordinates are never all held (13 MB
    on the 175 mm dome)."""
    import shapely

    gx, gy = np.frombuffer(gx), np.frombuffer(gy)
    shapely.prepare(poly)
    band = [shapely.contains_xy(poly, np.tile(gx, len(y)), np.repeat(y, len(gx)))
            for y in np.array_split(gy, max(1, -(-len(gy) // rows)))]
    inside = np.concatenate(band) if band else np.zeros(0, bool)
    inside.flags.writeable = False
    return inside


_STAMP_CHUNK = 1 << 16


def _stamp(samples, label, gx, gy, res, r, covered, owner, twice):
    """Mark the grid nodes (axes ``gx`` (nx,), ``gy`` (ny,) mm, ``res`` apart) within ``r`` of
    ``samples`` ((q, 2) mm) in ``covered`` ((nx * ny,) bool, row-major); of the nodes
    within 0.999 r, give ``owner`` ((nx * ny,) int32, -1: none yet) the label of a
    sample reaching them and mark in ``twice`` ((nx * ny,) bool) those that samples
    of two different labels reach."""
    nx, ny = len(gx), len(gy)
    # Each sample stamps the nodes within r of it: those lie in a box of
    # ``span`` nodes a side starting at the first node no further than r left
    # of (below) it. Stamping visits each (sample, node) pair once, where a
    # nearest-neighbour query per node walks a tree for every node.
    span = int(np.floor(2 * r / res)) + 1
    lo_x = np.ceil((samples[:, 0] - r - gx[0]) / res).astype(np.int64)
    lo_y = np.ceil((samples[:, 1] - r - gy[0]) / res).astype(np.int64)
    # Squared offsets to the candidate nodes along each axis; a node off the grid is infinitely far.
    along_x, along_y = [], []
    for ox in range(span):
        ix = lo_x + ox
        dx = gx[np.clip(ix, 0, nx - 1)] - samples[:, 0]
        along_x.append((ix, np.where((ix < 0) | (ix >= nx), np.inf, dx * dx)))
    for oy in range(span):
        iy = lo_y + oy
        dy = gy[np.clip(iy, 0, ny - 1)] - samples[:, 1]
        along_y.append((iy * nx, np.where((iy < 0) | (iy >= ny), np.inf, dy * dy)))
    for ix, dx2 in along_x:
        for row, dy2 in along_y:
            d2 = dx2 + dy2
            hit = np.flatnonzero(d2 <= r * r)
            cell = row[hit] + ix[hit]
            covered[cell] = True
            strict = d2[hit] < (0.999 * r) ** 2
            _own(owner, twice, cell[strict], label[hit[strict]])


def _own(owner, twice, cell, lab):
    """Give the nodes ``cell`` ((k,) int) the labels ``lab`` ((k,) int) in ``owner``, and
    mark in ``twice`` those a different label reached: one already there, or another of
    these (a node's owner is then one of its labels, which the others differ from)."""
    seen = owner[cell]
    twice[cell[(seen >= 0) & (seen != lab)]] = True
    owner[cell] = lab
    twice[cell[owner[cell] != lab]] = True


def isoline_angles(xy, faces, level, u):
    """How far the paths turn away from the isolines, per face.

    The paths are level sets of ``u`` and the isolines level sets of ``level``
    (both (n,) per vertex, linear per face), so in each face the angle between
    them is the angle between the two gradients, folded to 0..90 degrees.

    Returns
    -------
    angle_deg : (m,) float
    path_mm : (m,) float, length of path in the face (area times the density
        of level sets, ``|grad u|``: a weight for statistics over path length)
    """
    gphi, area = hat_gradients(xy, faces)
    gu = np.einsum("mi,mid->md", u[faces], gphi)
    gl = np.einsum("mi,mid->md", level[faces], gphi)
    nu, nl = np.linalg.norm(gu, axis=1), np.linalg.norm(gl, axis=1)
    cos = np.abs(np.einsum("md,md->m", gu, gl)) / np.maximum(nu * nl, 1e-300)
    angle = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
    path_mm = np.abs(area) * nu * ((nl > 1e-9) & (nu > 0))
    return angle, path_mm


def _weighted_percentiles(x, w, q):
    """Percentiles ``q`` (0-100) of ``x`` weighted by ``w`` (lower value at a tie)."""
    if not len(x) or w.sum() <= 0:
        return [0.0] * len(q)
    order = np.argsort(x)
    cw = np.cumsum(w[order]) / w.sum()
    idx = np.minimum(np.searchsorted(cw, np.asarray(q) / 100.0), len(x) - 1)
    return [float(v) for v in x[order][idx]]


