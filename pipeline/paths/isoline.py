"""Continuous, equally spaced tool paths on the flat layout (paper 6.3).

The paper fills each triangle between two isolines with segments parallel to
its printing edge, a path width apart, and traces them into a few long paths.
We get the same segments from one field: a *path index* ``u`` on the flat
mesh whose gradient follows the isolines' normal with magnitude 1/path_width
(the least-squares fit of that gradient field, one sparse solve). Its level
sets ``u = j + 1/2`` are the paths: in a triangle between two isolines they
run parallel to the printing edge, consecutive ones are a path width apart,
and being level sets of a continuous field they are closed loops or arcs that
end on the boundary: continuous by construction, never dangling inside.
Loops and arcs are then chained into traces by short hops to the neighbouring
path (the paper's bridge-edge steps) and travel moves only where no neighbour
is near (saddle regions).
"""

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from pipeline.geometry import boundary_loops, hat_gradients, unique_edges
from pipeline.linalg import factor_spd
from pipeline.paths.links import HOP
from pipeline.paths.stats import path_metrics


@dataclass
class Toolpaths:
    """Ordered traces of the flat sheet (mm, layout coordinates).

    traces : list of (k_i, 2) float, the points of each continuous trace
    sigma : list of (k_i - 1,) float, shrink ratio per segment
    chains : int, number of loops and arcs before chaining
    info : dict, the report's ``toolpath`` section
    dry : list of (k_i - 1,) bool, the segments moved without extruding (hops over
        printed paths, :mod:`pipeline.paths.dry`), or None: none
    """

    traces: list
    sigma: list
    chains: int = 0
    info: dict = field(default_factory=dict)
    dry: list = None


def path_field(xy, faces, level, path_width_mm, loop=None):
    """Path index per vertex.

    Parameters
    ----------
    xy : (n, 2) float, mm, flat layout (faces counter-clockwise)
    faces : (m, 3) int
    level : (n,) float, isoline value per vertex (rises toward peaks)
    path_width_mm : float
    loop : (k,) int, optional, the outer boundary (:func:`boundary_loop`), if known

    Returns
    -------
    u : (n,) float, 0 at the lowest vertex; level sets 1 apart are paths.
    """
    n = len(xy)
    gphi, area = hat_gradients(xy, faces)
    glevel = np.einsum("mi,mid->md", level[faces], gphi)
    norm = np.linalg.norm(glevel, axis=1)
    has_dir = norm > 1e-9
    target = np.where(has_dir[:, None], glevel / np.maximum(norm, 1e-12)[:, None], 0.0)
    target /= path_width_mm
    # Faces with no isoline direction (rare) only smooth the field; collapsed
    # faces (a folded layout) carry no gradient at all (hat_gradients zeroes them).
    w = np.abs(area) * np.where(has_dir, 1.0, 1e-3)
    w[np.abs(area) <= 1e-12] = 0.0
    m = len(faces)
    rows = np.stack([np.arange(m) * 2, np.arange(m) * 2 + 1], axis=1)[:, None, :]
    rows = np.broadcast_to(rows, (m, 3, 2))
    cols = np.broadcast_to(faces[:, :, None], (m, 3, 2))
    G = sp.csr_matrix((gphi.ravel(), (rows.ravel(), cols.ravel())), shape=(2 * m, n))
    W = sp.diags(np.repeat(w, 2))
    L = (G.T @ W @ G).tocsc()
    rhs = G.T @ (W @ target.ravel())
    # Pin the constant: the lowest vertex gets u = 0. Where the outline is itself an
    # isoline (a dome, an island), all of it is pinned so the outermost path follows it.
    pin = int(np.argmin(level))
    fixed = np.array([pin])
    loop = boundary_loop(faces) if loop is None else loop
    if np.ptp(level[loop]) < 1e-9:
        fixed = loop
    # A tiny ridge keeps vertices that only touch collapsed faces determined.
    penalty = np.full(n, 1e-9 * float(L.diagonal().mean()))
    penalty[fixed] = 1e6 * float(L.diagonal().mean())
    L = (L + sp.diags(penalty)).tocsc()
    u = factor_spd(L).solve(rhs)
    return u - u[pin]


def level_segments(xy, faces, u, values, eps=1e-9, edges=None):
    """Marching triangles: segments of the level sets ``u = values``.

    ``edges`` : (e, 2) int, the mesh's :func:`unique_edges`, if already at hand.

    Returns
    -------
    pts : (s, 2, 2) float, mm; each segment has higher ``u`` on its left
    keys : (s, 2) int64, an id per end point shared by the segment it meets
    edge_t : (s, 2, 3) (edge endpoint a, endpoint b, t) to interpolate per-vertex data
    level_id : (s,) int, index into ``values``
    """
    values = np.asarray(values, float)
    uf = u[faces]
    lo = np.searchsorted(values, uf.min(axis=1) + eps)
    hi = np.searchsorted(values, uf.max(axis=1) - eps)
    count = hi - lo
    f = np.repeat(np.arange(len(faces)), count)
    j = np.repeat(lo, count) + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))
    L = values[j]
    v = faces[f]                                     # (s, 3)
    s = u[v] - L[:, None]
    s = np.where(np.abs(s) < eps, eps, s)
    neg = s < 0
    # Edge k joins corner k and k+1; a level crosses it where the signs differ.
    cross = neg != np.roll(neg, -1, axis=1)          # (s, 3)
    # The crossing where u goes from below to above (walking the face CCW) is the start.
    k_in = np.argmax(cross & neg, axis=1)            # edge whose start is below
    k_out = np.argmax(cross & ~neg, axis=1)          # edge whose start is above
    idx = np.arange(len(f))
    ends = []
    for k in (k_out, k_in):
        a = v[idx, k]
        b = v[idx, (k + 1) % 3]
        sa, sb = s[idx, k], s[idx, (k + 1) % 3]
        t = sa / (sa - sb)
        ends.append((a, b, t))
    pts = np.stack([xy[a] + (xy[b] - xy[a]) * t[:, None] for a, b, t in ends], axis=1)
    edges = unique_edges(faces) if edges is None else edges
    nv = len(xy)
    ekey = edges[:, 0] * nv + edges[:, 1]
    keys = []
    for a, b, _ in ends:
        q = np.minimum(a, b) * nv + np.maximum(a, b)
        keys.append(np.searchsorted(ekey, q) * len(values) + j)
    edge_t = np.stack([np.stack([a, b, t], axis=1) for a, b, t in ends], axis=1)
    return pts, np.stack(keys, axis=1).astype(np.int64), edge_t, j


def chain_segments(pts, keys):
    """Join level-set segments end to start into polylines.

    Returns a list of ``(order (k,) int segment ids, closed bool)``.
    """
    s = len(pts)
    # Successor of each segment: the one starting where it ends (the last such
    # segment when several do, as a dict would keep), by a sorted lookup.
    order = np.argsort(keys[:, 0], kind="stable")
    sk = keys[order, 0]
    pos = np.searchsorted(sk, keys[:, 1], side="right") - 1
    found = (pos >= 0) & (sk[np.maximum(pos, 0)] == keys[:, 1])
    nxt = np.where(found, order[np.maximum(pos, 0)], -1).astype(np.int64)
    has_prev = np.zeros(s, bool)
    has_prev[nxt[nxt >= 0]] = True
    # The walk is a Python loop over every segment: on lists, not numpy scalars.
    nxt = nxt.tolist()
    seen = bytearray(s)
    chains = []
    # Open chains first (they start where a level set meets the boundary), then loops.
    for start in np.nonzero(~has_prev)[0].tolist() + list(range(s)):
        if seen[start]:
            continue
        order = []
        i = start
        while i >= 0 and not seen[i]:
            seen[i] = 1
            order.append(i)
            i = nxt[i]
        chains.append((np.asarray(order, dtype=np.int64), i == start))
    return chains


def vertex_sigma(n, printing_edges, sigma, edges):
    """Shrink ratio per vertex: mean of its printing edges, else of its neighbours.

    n : int; printing_edges : (p, 2) int; sigma : (p,); edges : (e, 2) all mesh edges.
    Returns (n,) float.
    """
    total = np.bincount(printing_edges.ravel(), np.repeat(sigma, 2), minlength=n)
    count = np.bincount(printing_edges.ravel(), minlength=n).astype(float)
    out = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    for _ in range(3):
        missing = np.isnan(out)
        if not missing.any():
            break
        a, b = edges[:, 0], edges[:, 1]
        val = np.nan_to_num(out)
        has = ~np.isnan(out)
        tot = np.bincount(a, val[b] * has[b], minlength=n) + np.bincount(b, val[a] * has[a], minlength=n)
        cnt = np.bincount(a, has[b], minlength=n) + np.bincount(b, has[a], minlength=n)
        fill = missing & (cnt > 0)
        out[fill] = tot[fill] / cnt[fill]
    # No printing edge anywhere (a synthetic layout): no shrink is known, use 0.
    fallback = float(np.nanmean(out)) if np.isfinite(out).any() else 0.0
    return np.where(np.isnan(out), fallback, out)


def merge_collinear(points, sigma, angle_deg, sigma_tol):
    """Merge consecutive segments within ``angle_deg`` of the run's direction and
    ``sigma_tol`` of its first sigma; the merged sigma is the length-weighted mean.

    points : (k, 2); sigma : (k - 1,). Returns (points', sigma').
    """
    k = len(points)
    if k <= 2:
        return points, sigma
    d = np.diff(points, axis=0)
    seg_len = np.hypot(d[:, 0], d[:, 1])
    # Where a run ends depends on where it started, so the scan is sequential; on
    # Python floats it is ~10x faster than on numpy scalars (a dome has ~150k segments).
    sigma = np.asarray(sigma, dtype=float)
    ang = np.arctan2(d[:, 1], d[:, 0]).tolist()
    sg = sigma.tolist()
    cos_tol = math.cos(math.radians(angle_deg))
    keep = [0]
    i = 0
    nseg = k - 1
    while i < nseg:
        j = i + 1
        a0, s0 = ang[i], sg[i]
        while j < nseg and abs(sg[j] - s0) < sigma_tol and math.cos(ang[j] - a0) >= cos_tol:
            j += 1
        keep.append(j)
        i = j
    # Length-weighted mean sigma per run, from prefix sums.
    ends = np.asarray(keep)
    cw = np.concatenate([[0.0], np.cumsum(seg_len)])
    # A hop's unknown shrink (HOP) is a run of its own, and must not leak into the sums.
    hop = np.isnan(sigma)
    cws = np.concatenate([[0.0], np.cumsum(seg_len * np.where(hop, 0.0, sigma))])
    w = cw[ends[1:]] - cw[ends[:-1]]
    out_sigma = (cws[ends[1:]] - cws[ends[:-1]]) / np.maximum(w, 1e-12)
    return points[keep], np.where(hop[ends[:-1]], np.nan, out_sigma)


def plan_toolpaths(xy, faces, level, printing_edges, sigma, path_width_mm,
                   merge_angle_deg=2.0, merge_sigma=0.005, link_factor=1.6):
    """Tool paths for the flat layout.

    Parameters
    ----------
    xy : (n, 2) float, mm, flat layout; faces : (m, 3) int, counter-clockwise
    level : (n,) float, isoline value per vertex (``Mesh.vertex_level``)
    printing_edges : (p, 2) int; sigma : (p,) float, shrink per printing edge
    path_width_mm : float
    merge_angle_deg, merge_sigma : tolerances for merging consecutive segments
    link_factor : hops up to ``link_factor * path_width_mm`` join paths into one trace

    Returns
    -------
    Toolpaths
    """
    pw = float(path_width_mm)
    loop = boundary_loop(faces)
    u = path_field(xy, faces, level, pw, loop=loop)
    values = np.arange(np.floor(u.min()) + 0.5, u.max(), 1.0)
    edges = unique_edges(faces)
    pts, keys, edge_t, seg_level = level_segments(xy, faces, u, values, edges=edges)
    sv = vertex_sigma(len(xy), printing_edges, sigma, edges)
    a = edge_t[..., 0].astype(np.int64)
    b = edge_t[..., 1].astype(np.int64)
    end_sigma = sv[a] + (sv[b] - sv[a]) * edge_t[..., 2]          # (s, 2)
    seg_sigma = end_sigma.mean(axis=1)
    chains = []
    raw = []
    levels = []
    for order, closed in chain_segments(pts, keys):
        p = np.vstack([pts[order, 0], pts[order[-1], 1][None]])
        sg = seg_sigma[order]
        raw.append((p, closed))
        levels.append(int(seg_level[order[0]]))
        if closed:
            p = p[:-1]
        chains.append((p, sg, closed))
    children = _nesting(chains, levels)
    import shapely
    outline = _outline_polygon(xy, loop)
    footprint = outline.buffer(0.25 * pw)
    shapely.prepare(footprint)
    traces, tsig = _order_traces(chains, children, pw * link_factor, merge_angle_deg,
                                 merge_sigma, footprint)
    return finished(traces, tsig, raw, xy, faces, level, u, outline, pw, len(chains))


def finished(traces, tsig, raw, xy, faces, level, u, outline, pw, chains, samples=None):
    """:class:`Toolpaths` of ordered ``traces`` whose joins are still to be split into
    extruded and dry stretches (:func:`pipeline.paths.dry.finish`), with the report's
    figures (:func:`pipeline.paths.stats.path_metrics`; ``samples`` as it takes them)."""
    from pipeline.paths.dry import dry_figures, finish
    from pipeline.paths.links import path_samples
    if samples is None:
        samples = path_samples([p for p, _ in raw], pw)
    traces, tsig, dry, hops, over = finish(traces, tsig, *samples, pw)
    info = path_metrics(traces, tsig, raw, xy, faces, level, u, outline, pw, hops=hops,
                        samples=samples, hop_over=over)
    info.update(dry_figures(traces, dry))
    return Toolpaths(traces=traces, sigma=tsig, chains=chains, info=info, dry=dry)


def _nesting(chains, levels):
    """For each loop, the loops one level up that it encloses (its children)."""
    import shapely

    children = [[] for _ in chains]
    loops = [c for c, ch in enumerate(chains) if ch[2] and len(ch[0]) >= 3]
    by_level = {}
    for c in loops:
        by_level.setdefault(levels[c], []).append(c)
    for c in loops:
        inner = by_level.get(levels[c] + 1, [])
        if not inner:
            continue
        poly = shapely.Polygon(chains[c][0])
        probe = np.array([chains[k][0][0] for k in inner])
        inside = shapely.contains_xy(poly, probe[:, 0], probe[:, 1])
        children[c] = [k for k, ok in zip(inner, inside) if ok]
    return children


def _order_traces(chains, children, link_mm, merge_angle_deg, merge_sigma, footprint):
    """Chain loops and arcs into traces, outermost first, by nearest hops.

    After a loop, its enclosed loops come next (so a peak is printed in one
    go, outside in); otherwise the nearest unvisited path. Arcs that meet the
    edge at a slant end further apart than a path width: a hop of up to three
    link lengths still joins them where it runs inside the sheet (along its edge).
    With ``link_mm`` 0 the paths are only put in order, each a trace of its own.

    Returns (traces, sigma per segment: ``HOP`` at the hops, see
    :mod:`pipeline.paths.dry`).
    """
    import shapely

    entries, owner, index = [], [], []
    for c, (p, _, closed) in enumerate(chains):
        idx = np.arange(len(p)) if closed else np.array([0, len(p) - 1])
        entries.append(p[idx])
        owner.append(np.full(len(idx), c))
        index.append(idx)
    entries = np.concatenate(entries)
    owner = np.concatenate(owner)
    index = np.concatenate(index)
    # Built when first asked: a stripe set joined into a ring or two asks it once or
    # never (the 175 mm dome's one ring: 0.07 s a set for its 233 thousand entries).
    tree = functools.cache(lambda: cKDTree(entries))
    visited = np.zeros(len(chains), bool)
    traces, tsig = [], []
    cur_p, cur_s = None, None
    # Start at the outermost path nearest the front-left corner.
    c0 = int(owner[np.argmin(entries[:, 0] + entries[:, 1])])
    nxt = (c0, int(index[owner == c0][0]), 0.0)
    limit = link_mm
    while nxt is not None:
        c, e, dist = nxt
        p, sg, closed = chains[c]
        if closed:
            p = np.vstack([np.roll(p, -e, axis=0), np.roll(p, -e, axis=0)[:1]])
            sg = np.roll(sg, -e)
        elif e != 0:
            p, sg = p[::-1], sg[::-1]
        p, sg = merge_collinear(p, sg, merge_angle_deg, merge_sigma)
        visited[c] = True
        linked = cur_p is not None and (dist <= limit or (
            dist <= 3 * link_mm and not closed and footprint.contains(
                shapely.LineString([cur_p[-1], p[0]]))))
        if linked:
            cur_p = np.vstack([cur_p, p])
            cur_s = np.concatenate([cur_s, [HOP], sg])
        else:
            if cur_p is not None:
                traces.append(cur_p)
                tsig.append(cur_s)
            cur_p, cur_s = p, np.asarray(sg, float)
        inner = [k for k in children[c] if not visited[k]]
        if inner:
            # A loop's own inner neighbour is always the next path in; where the
            # spacing opens up (near saddles) a longer hop still beats a travel.
            nxt = _nearest_in(chains, inner, cur_p[-1], ahead_mm=link_mm)
            limit = 3.5 * link_mm
        else:
            nxt = _nearest_entry(tree, entries, owner, index, visited, cur_p[-1])
            limit = link_mm
    if cur_p is not None:
        traces.append(cur_p)
        tsig.append(cur_s)
    return traces, tsig


def _nearest_in(chains, cands, at, ahead_mm=0.0):
    """Nearest entry among chains ``cands``; on a loop, moved ``ahead_mm`` further
    along it so the hop is a gentle lane change rather than a right angle."""
    best = None
    for c in cands:
        p, _, closed = chains[c]
        d = np.linalg.norm(p - at, axis=1)
        if not closed:
            d = d[[0, -1]]
        k = int(np.argmin(d))
        e = k if closed else (0 if k == 0 else len(p) - 1)
        if closed and ahead_mm > 0:
            q = np.roll(p, -k, axis=0)
            run = np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))
            step = int(np.searchsorted(run, ahead_mm)) + 1
            e = (k + min(step, len(p) // 4)) % len(p)
            d_e = float(np.linalg.norm(p[e] - at))
        else:
            d_e = float(d[k])
        if best is None or d[k] < best[3]:
            best = (c, e, d_e, float(d[k]))
    return best[:3]


def _nearest_entry(tree, entries, owner, index, visited, at):
    """The unvisited entry nearest ``at`` as (chain, entry index, distance mm), None
    where all are visited; ``tree``: a function giving the KD-tree of ``entries``."""
    if visited.all():
        return None
    k = min(64, len(entries))
    d, i = tree().query(at, k=k)
    i = np.atleast_1d(i)
    d = np.atleast_1d(d)
    ok = ~visited[owner[i]]
    if ok.any():
        j = i[np.argmax(ok)]
        return int(owner[j]), int(index[j]), float(d[np.argmax(ok)])
    free = np.nonzero(~visited[owner])[0]
    dd = np.linalg.norm(entries[free] - at, axis=1)
    j = free[np.argmin(dd)]
    return int(owner[j]), int(index[j]), float(dd.min())


def boundary_loop(faces):
    """Outer boundary vertex ids of a disk mesh in order: (k,) int."""
    return boundary_loops(faces)[0]


def _outline_polygon(xy, loop):
    """The flat sheet's outline (``loop``: boundary vertex ids in order) as a valid
    polygon (a folded layout self-intersects)."""
    import shapely

    poly = shapely.Polygon(xy[loop])
    return poly if poly.is_valid else shapely.make_valid(poly)
