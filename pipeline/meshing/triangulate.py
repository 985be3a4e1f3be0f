"""Triangulating the cells of the isoline/gradient-line graph (paper 6.1, Fig. 5c-d).

Cells between two isolines are zipped greedily by the shortest diagonal;
polygons at peaks and saddles are fanned around an inserted centre vertex,
with ear clipping as the fallback where a fan would fold over itself.
The same cells, with fewer isoline vertices, give the coarser sheet the
forward simulation runs on (:func:`sim_sheet`).
"""

from collections import Counter

import mapbox_earcut
import numpy as np
import shapely

from pipeline.geometry import SimSheet, polygon_area, signed_areas_2d


def zip_strips(points, lowers, uppers):
    """Greedy shortest-diagonal triangulation of strips between two chains.

    Each strip is bounded by chain ``L`` (walked forward along the cell's
    counter-clockwise boundary) and chain ``U`` (walked backward), with the
    rungs ``(L[0], U[0])`` and ``(L[-1], U[-1])`` on the cell boundary.

    Parameters
    ----------
    points : (n, 3) float, mm (distances are measured on the target surface)
    lowers, uppers : list of (k_i,) int vertex ids, one pair per strip

    Returns
    -------
    faces : (m, 3) int, counter-clockwise when the cells are.
    strip : (m,) int, the strip each face belongs to.
    """
    if not lowers:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    nl = np.array([len(a) for a in lowers])
    nu = np.array([len(a) for a in uppers])
    L = _pad(lowers, nl.max())
    U = _pad(uppers, nu.max())
    i = np.zeros(len(nl), dtype=np.int64)
    j = np.zeros(len(nu), dtype=np.int64)
    out = []
    owner = []
    active = np.nonzero((nl > 1) | (nu > 1))[0]
    while len(active):
        ia, ja = i[active], j[active]
        can_l = ia < nl[active] - 1
        can_u = ja < nu[active] - 1
        li, lj = L[active, ia], U[active, ja]
        l_next = L[active, np.minimum(ia + 1, nl[active] - 1)]
        u_next = U[active, np.minimum(ja + 1, nu[active] - 1)]
        d_l = _d2(points, l_next, lj)
        d_u = _d2(points, li, u_next)
        # Shortest diagonal, unless it would fold the triangle over in the plane.
        ok_l = _area2(points, li, l_next, lj) > 0
        ok_u = _area2(points, li, u_next, lj) > 0
        prefer_l = np.where(ok_l == ok_u, d_l <= d_u, ok_l)
        take_l = can_l & (~can_u | prefer_l)
        take_u = can_u & ~take_l
        out.append(np.stack([li, l_next, lj], axis=1)[take_l])
        out.append(np.stack([li, u_next, lj], axis=1)[take_u])
        owner.append(active[take_l])
        owner.append(active[take_u])
        i[active] += take_l
        j[active] += take_u
        active = active[(i[active] < nl[active] - 1) | (j[active] < nu[active] - 1)]
    if not out:
        return np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(out), np.concatenate(owner)


def _pad(chains, width):
    m = np.zeros((len(chains), width), dtype=np.int64)
    for r, c in enumerate(chains):
        m[r, :len(c)] = c
    return m


def _area2(points, a, b, c):
    p, q, r = points[a], points[b], points[c]
    return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])


def _d2(points, a, b):
    d = points[a] - points[b]
    return np.einsum("ij,ij->i", d, d)


def fan(xy, ring, centre_id, centre_xy):
    """Fan triangles ``(centre, ring[k], ring[k+1])`` or None if any would fold.

    xy : (n, 2) float, vertex positions; ring : (k,) int, a counter-clockwise cycle.
    """
    a = xy[ring] - centre_xy
    b = np.roll(xy[ring], -1, axis=0) - centre_xy
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    if np.any(cross <= 1e-12):
        return None
    return np.stack([np.full(len(ring), centre_id), ring, np.roll(ring, -1)], axis=1)


def drop_degenerate(faces):
    """``faces`` ((m, 3) int) without those that repeat a vertex."""
    return faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
                 & (faces[:, 0] != faces[:, 2])]


def ear_clip(xy, ring):
    """Triangulate a simple polygon (counter-clockwise ``ring`` of vertex ids)."""
    coords = np.ascontiguousarray(xy[ring], dtype=np.float64)
    tri = mapbox_earcut.triangulate_float64(coords, np.array([len(ring)], dtype=np.uint32))
    tri = ring[np.asarray(tri, dtype=np.int64).reshape(-1, 3)]
    p = xy[tri]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - \
        (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])
    tri[area < 0] = tri[area < 0][:, [0, 2, 1]]
    return tri


# -- cells of the planar graph ---------------------------------------------
def split_arcs(ts, ns, period, l_mm, first_id):
    """Cut the arcs between a piece's consecutive nodes into edges of at most ``l_mm``.

    Parameters
    ----------
    ts : (m,) float, sorted arc-length parameters of the nodes, mm
    ns : (m,) int, the nodes' vertex ids
    period : float, the length of a closed piece (its last arc runs on to ts[0] + period);
        None for an open piece
    l_mm : float
    first_id : int, vertex id of the first inserted vertex (the rest follow in order)

    Returns
    -------
    t_inner : (q,) float, parameters of the vertices inserted, arc by arc
    seq : (a + q + 1,) int, the piece's vertex ids in order: node, inserted, node, ...
    pos : (a + 1,) int, where each arc's first node (and last, the end node) is in ``seq``
    lengths : (a,) float, mm
    """
    tb = ts[1:] if period is None else np.append(ts[1:], ts[0] + period)
    ta = ts[:len(tb)]
    lengths = tb - ta
    nsub = np.maximum(np.ceil(lengths / l_mm - 1e-9).astype(np.int64), 1)
    cum = np.concatenate([[0], np.cumsum(nsub - 1)])
    arc = np.repeat(np.arange(len(ta)), nsub - 1)
    j = np.arange(len(arc)) - cum[arc] + 1          # 1 .. nsub - 1 within each arc
    # Same arithmetic, in the same order, as ta + (tb - ta) * arange(1, nsub) / nsub.
    t_inner = ta[arc] + lengths[arc] * j / nsub[arc]
    pos = np.arange(len(ta) + 1) + cum
    seq = np.empty(pos[-1] + 1, dtype=np.int64)
    seq[pos] = ns[np.arange(len(pos)) % len(ns)]
    inserted = np.ones(len(seq), bool)
    inserted[pos] = False
    seq[inserted] = first_id + np.arange(len(t_inner))
    return t_inner, seq, pos, lengths


def run_keys(he, pieces):
    """Per half-edge: the printing piece it runs along, or -1 (bridges, a sloped outline)."""
    printing = [not np.isnan(p.level) for p in pieces]
    return [h[2] if h[2] >= 0 and printing[h[2]] else -1 for h in he]


def main_runs(keys):
    """Maximal runs of a cell's half-edges along one printing isoline, in cycle order.

    keys : per half-edge of the cell's cycle, its :func:`run_keys` entry.
    Returns a list of runs, each a list of positions in the cycle.
    """
    n = len(keys)
    if all(k == keys[0] for k in keys):
        return [list(range(n))] if keys[0] >= 0 else []
    start = next(i for i in range(n) if keys[i] != keys[i - 1])
    runs, cur = [], []
    for s in range(n):
        i = (start + s) % n
        if cur and keys[i] != keys[cur[-1]]:
            if keys[cur[-1]] >= 0:
                runs.append(cur)
            cur = []
        cur.append(i)
    if cur and keys[cur[-1]] >= 0:
        runs.append(cur)
    return runs


def run_level(run, cycle, he, pieces):
    return pieces[he[cycle[run[0]]][2]].level


def split_ring(ring, offs, run, swap=False):
    """Split a cell's ring into the chain of ``run`` (U) and the rest (L).

    ring : (n,) int, the cell's vertices; offs : where each half-edge of its cycle
    starts in ``ring`` (then n), as :func:`cell_rings` gives them.
    Returns ``(L, U_reversed)`` as ``zip_strips`` wants them; with ``swap``
    the run is L instead (for cells closed by a single apex vertex).
    """
    n = len(ring)
    s = offs[run[0]]
    e = offs[run[-1] + 1] % n  # the run's end vertex: first vertex of the next half-edge
    k = (e - s) % n            # edges along the run
    twice = np.concatenate([ring, ring])   # slices that wrap around need no index arrays
    chain_u = twice[s:s + k + 1]
    rest = twice[e + 1:e + n - k]
    if swap:
        # The run is the lower chain; the rest (one apex) is the upper.
        return chain_u, rest[::-1]
    return rest, chain_u[::-1]


def cell_rings(xy, he, faces):
    """The vertex rings of the graph's faces, and which of them are cells.

    xy : (n, 2) float, mm; he : half-edges as :func:`trace_faces` takes them;
    faces : its cycles. Returns ``(rings, offsets, is_cell)``: per face its ring
    ((k,) int, the half-edges' vertex lists joined), where each half-edge starts in
    the ring (then k), and whether the ring is counter-clockwise (else it is an
    outer face), as ``polygon_area(xy[ring]) > 0`` says.
    """
    flat, starts, offsets = [], [0], []
    for cyc in faces:
        offs = [0]
        for h in cyc:
            flat.extend(he[h][3])
            offs.append(len(flat) - starts[-1])
        starts.append(len(flat))
        offsets.append(offs)
    if not flat:
        return [], [], np.zeros(0, bool)
    flat = np.array(flat, dtype=np.int64)
    starts = np.array(starts)
    rings = [flat[a:b] for a, b in zip(starts[:-1], starts[1:])]
    # Shoelace sums of all rings at once.
    nxt = np.arange(1, len(flat) + 1)
    nxt[starts[1:] - 1] = starts[:-1]
    x, y = xy[flat, 0], xy[flat, 1]
    a, b = x * y[nxt], y * x[nxt]
    area2 = np.add.reduceat(a - b, starts[:-1])
    bound = np.add.reduceat(np.abs(a) + np.abs(b), starts[:-1])
    is_cell = area2 > 0
    # Only near zero could rounding in another summation order flip the sign:
    # there polygon_area itself decides, as it always did.
    for k in np.nonzero(np.abs(area2) <= 1e-9 * bound)[0]:
        is_cell[k] = polygon_area(xy[rings[k]]) > 0
    return rings, offsets, is_cell


def pull_inside(xy, ring, clipped_to, min_mm=1e-4):
    """Put back inside the outline the vertices its resampling left outside.

    The isolines were clipped to the outline polyline ``clipped_to`` (a shapely
    LinearRing), but the mesh's outline is ``ring`` ((k,) int, counter-clockwise
    vertex ids of ``xy`` (n, 2) mm): the same polyline cut anew into edges of at most
    l_u, whose chords cut its bends by up to a quarter of l_u times the bend. An
    isoline that runs nearly tangent to the outline, closer than that, crosses it:
    the ring of the cell between them crosses itself and ear clipping left a hole
    (seed 36 of the random terrains: 2 mm^2 beside the outline, one vertex 2 microns
    out). Each such vertex is moved in from the nearest point of the ring by the
    clearance it had from the polyline it was clipped to (at least ``min_mm``), so it
    moves by about the chord error. Returns ``xy``, a copy where a vertex moved.
    """
    rest = np.ones(len(xy), bool)
    rest[ring] = False
    ids = np.flatnonzero(rest)
    poly = shapely.Polygon(xy[ring])
    out = ids[~shapely.contains_xy(poly, xy[ids, 0], xy[ids, 1])]
    if not len(out):
        return xy
    pts = shapely.points(xy[out])
    s = shapely.line_locate_point(poly.exterior, pts)
    near = shapely.get_coordinates(shapely.line_interpolate_point(poly.exterior, s))
    # Inward normal of the ring's edge there: the inside is on the left.
    loop = np.vstack([xy[ring], xy[ring[:1]]])
    d = np.diff(loop, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(d[:, 0], d[:, 1]))])
    edge = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(ring) - 1)
    normal = np.stack([-d[edge, 1], d[edge, 0]], axis=1)
    normal /= np.maximum(np.hypot(normal[:, 0], normal[:, 1]), 1e-12)[:, None]
    clearance = np.maximum(shapely.distance(clipped_to, pts), min_mm)
    xy = xy.copy()
    xy[out] = near + clearance[:, None] * normal
    return xy


def trace_faces(xy, he):
    """Faces of the planar graph: cycles of half-edges with the face on the left."""
    n = len(he)
    frm = np.array([h[0] for h in he])
    to = np.array([h[1] for h in he])
    second = np.array([h[3][1] if len(h[3]) > 1 else h[1] for h in he])
    d = xy[second] - xy[frm]
    ang = np.arctan2(d[:, 1], d[:, 0])
    twin = np.arange(n) ^ 1
    order = np.lexsort((ang, frm))
    pos = np.empty(n, dtype=np.int64)
    counts = np.bincount(frm, minlength=len(xy))
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pos[order] = np.arange(n) - start[frm[order]]
    nxt = order[start[to] + np.mod(pos[twin] - 1, counts[to])]
    seen = np.zeros(n, bool)
    faces = []
    for h0 in range(n):
        if seen[h0]:
            continue
        cyc = []
        h = h0
        while not seen[h]:
            seen[h] = True
            cyc.append(h)
            h = nxt[h]
        faces.append(cyc)
    return faces


# -- the coarse sheet --------------------------------------------------------
def sim_sheet(points, n_nodes, n_ring, arcs, bridges, zips, fans, l_mm):
    """The cells triangulated again with arcs cut to pieces of at most ``l_mm``.

    Parameters
    ----------
    points : (n, 3) float, mm
        All vertices: graph nodes first (``n_nodes``), then the vertices
        upsampled along arcs, then cell centres (from ``n_ring`` on).
    arcs : list of ((k,) int vertex chain from node to node, length mm)
    bridges : list of (node, node)
    zips : (lowers, uppers, rings) of the zipped cells, as for :func:`zip_strips`
    fans : list of (ring, centre id or -1 where the cell was ear-clipped)
    l_mm : float

    Returns
    -------
    SimSheet
    """
    keep = np.zeros(len(points), bool)
    keep[:n_nodes] = True
    keep[n_ring:] = True
    # All arcs' chains back to back: arc i is flat[first[i]:first[i] + size[i]].
    size = np.array([len(c) for c, _ in arcs], dtype=np.int64)
    first = np.cumsum(size) - size
    flat = np.concatenate([c for c, _ in arcs] or [np.zeros(0, np.int64)])
    lengths = np.array([length for _, length in arcs], float)
    pieces = np.maximum(np.ceil(lengths / l_mm - 1e-9).astype(np.int64), 1).tolist()
    # An arc cut to one edge must not join two vertices that another arc or a
    # bridge already joins: the cell between them would have two sides.
    ends = [tuple(e) for e in
            np.sort(np.column_stack([flat[first], flat[first + size - 1]]), axis=1).tolist()]
    joined = Counter(e for e, k in zip(ends, pieces) if k == 1)
    joined.update(tuple(sorted(b)) for b in bridges)
    for i, e in enumerate(ends):
        if e[0] == e[1]:
            pieces[i] = max(pieces[i], 3)
        elif pieces[i] == 1 and joined[e] > 1:
            pieces[i] = 2
    # Keep vertices rint(j * m / k), j = 1 .. k - 1, of each arc of m edges cut to k.
    m = size - 1
    k = np.minimum(np.asarray(pieces, dtype=np.int64), m)
    arc = np.repeat(np.arange(len(arcs)), k - 1)
    j = np.arange(len(arc)) - (np.cumsum(k - 1) - (k - 1))[arc] + 1
    keep[flat[first[arc] + np.rint(j * m[arc] / k[arc]).astype(np.int64)]] = True
    for ring, cid in fans:
        if cid < 0:
            keep[ring] = True   # rare; the mesh's own ear clipping stands
    # A coarse cell that folds gets its full ring back; a full cell is what the
    # mesh has and is never refused, so each round keeps more vertices and this ends.
    for _ in range(len(zips[2]) + len(fans) + 1):
        faces, bad = _coarse_cells(points, keep, zips, fans)
        if not bad:
            break
        keep[np.concatenate(bad)] = True
    faces = drop_degenerate(faces)
    kept = keep[flat]
    gone = np.nonzero(~kept)[0]
    if not len(gone):
        return SimSheet(faces, np.zeros(0, np.int64), np.zeros((0, 2), np.int64), np.zeros(0))
    # The kept vertices either side; every arc ends in kept nodes, so none is another arc's.
    pos = np.arange(len(flat))
    a = np.maximum.accumulate(np.where(kept, pos, 0))[gone]
    b = np.minimum.accumulate(np.where(kept, pos, len(flat))[::-1])[::-1][gone]
    return SimSheet(faces, flat[gone], np.stack([flat[a], flat[b]], axis=1),
                    (gone - a) / (b - a))


def _coarse_cells(points, keep, zips, fans):
    """Triangulate every cell over its kept vertices.

    Returns (faces (m, 3) int, rings of the cells that folded).
    """
    lowers, uppers, rings = zips
    full = np.array([bool(keep[r].all()) for r in rings], bool)
    lo = [a[keep[a]] for a in lowers]
    up = [a[keep[a]] for a in uppers]
    zipped, strip = zip_strips(points, lo, up)
    bad_strip = np.zeros(len(rings), bool)
    bad_strip[strip[signed_areas_2d(points, zipped) <= 0]] = True
    bad_strip |= np.array([len(a) + len(b) < 3 for a, b in zip(lo, up)], bool) & ~full
    out = [zipped[~bad_strip[strip]]] if len(zipped) else []
    bad = []
    for k in np.nonzero(bad_strip)[0]:
        if full[k]:
            out.append(ear_clip(points[:, :2], rings[k]))   # as the mesh did
        else:
            bad.append(rings[k])
    xy = points[:, :2]
    for ring, cid in fans:
        if cid < 0:
            out.append(ear_clip(xy, ring))
            continue
        rc = ring[keep[ring]]
        tris = fan(xy, rc, cid, xy[cid]) if len(rc) >= 3 else None
        if tris is None and len(rc) == len(ring):
            tris = ear_clip(xy, ring)
        if tris is None:
            bad.append(ring)
        else:
            out.append(tris)
    faces = np.concatenate(out) if out else np.zeros((0, 3), np.int64)
    return faces.astype(np.int64), bad
