"""Is a height field printable as one sheet? Topology, depressions, bed fit (paper 4(2), 8).

The sheet is a disk: the footprint must be one piece without holes. It pops up
in one direction, so closed depressions (a crater at a summit, a bowl) cannot
form; real terrain has many small ones (pits, resampling ripples), which are
filled up to ``max_fill_mm`` as terrain tools do ("fill sinks"), deeper ones
are refused with their position and depth.

The fill is computed without a per-cell heap: every cell is assigned, by
vectorised steepest descent with pointer jumping, to the pit (or the footprint
boundary, "ocean") it drains into; the basins form a small graph whose edges
are the lowest passes between neighbouring basins. Merging basins in order of
pass height (Kruskal on the basin graph, minimum spanning tree from scipy)
gives every depression's spill level and depth (its persistence) exactly as
priority-flood would. Filled flats then get an epsilon slope toward their
outlet (distances from csgraph), so every filled cell has a strictly
descending path to the boundary. ``pipeline.input.simplify`` reuses the same
machinery on the negated field to cut low peaks.
"""

from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra, minimum_spanning_tree
from scipy.spatial import ConvexHull, QhullError

from pipeline.errors import InvalidHeightField, PlanError
from pipeline.geometry import HeightField

# Neighbour offsets (row, col); the last four are the "forward" half used for edges.
_OFFSETS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))
_FORWARD = (4, 5, 6, 7)
# Default epsilon slope on filled flats, mm per cell step.
EPS_MM = 1e-4


class Grid:
    """Footprint cells of a (rows, cols) grid with their 8 neighbours.

    Attributes
    ----------
    rows, cols : (k,) int, grid index of each footprint cell (row-major order,
        the same order as ``z[footprint]``)
    nb : (k, 8) int32, neighbour cell ids (-1 outside the footprint)
    boundary : (k,) bool, cell touches the outside (8-neighbourhood)
    """

    def __init__(self, footprint):
        footprint = np.asarray(footprint, bool)
        rows, cols = footprint.shape
        width = cols + 2
        pad = np.zeros((rows + 2, width), bool)
        pad[1:-1, 1:-1] = footprint
        cells = np.flatnonzero(pad)
        pos = np.full(pad.size, -1, np.int32)
        pos[cells] = np.arange(len(cells), dtype=np.int32)
        offs = np.array([dr * width + dc for dr, dc in _OFFSETS])
        self.nb = pos[cells[:, None] + offs]
        self.boundary = (self.nb < 0).any(axis=1)
        r, c = np.divmod(cells, width)
        self.rows, self.cols = r - 1, c - 1
        self.k = len(cells)

    def neighbour_values(self, v, outside=np.inf):
        """(k, 8) values of the neighbours, ``outside`` where there is none."""
        return np.where(self.nb >= 0, v[self.nb], outside)

    def forward_edges(self, mask=None):
        """Undirected 8-neighbour edges (a, b) between cells (both in ``mask`` if given)."""
        a_all, b_all = [], []
        for col in _FORWARD:
            b = self.nb[:, col]
            ok = b >= 0
            if mask is not None:
                ok &= mask & mask[np.where(ok, b, 0)]
            a_all.append(np.flatnonzero(ok))
            b_all.append(b[ok].astype(np.int64))
        return np.concatenate(a_all), np.concatenate(b_all)


def _drain_roots(v, g):
    """Cell each cell drains to by steepest descent: a pit's id, or ``k`` (the outside)."""
    k = g.k
    vn = g.neighbour_values(v)
    j = vn.argmin(axis=1)
    ar = np.arange(k)
    ptr = np.where(vn[ar, j] < v, g.nb[ar, j], ar).astype(np.int64)
    ptr[g.boundary] = k  # the boundary drains off the sheet
    ptr = np.append(ptr, k)
    while True:  # pointer jumping: log2(longest descent) rounds
        nxt = ptr[ptr]
        if np.array_equal(nxt, ptr):
            return ptr[:k]
        ptr = nxt


def merge_levels(v, g, threshold=np.inf):
    """Depression levels by merging drainage basins in order of their passes.

    Parameters
    ----------
    v : (k,) float, values on the grid's cells (mm)
    g : Grid
    threshold : float
        Fill a depression only if its depth (spill level minus its bottom,
        i.e. its persistence) is at most this; inf fills all of them.

    Returns
    -------
    level : (k,) float
        Fill level per cell (``max(v, level)`` is the filled field); -inf where
        nothing is filled.
    events : (e, 4) float array: columns bottom cell id, spill level, depth,
        filled (1/0); one row per depression of positive depth, deepest first.
    """
    roots = _drain_roots(v, g)
    pits, label = np.unique(roots, return_inverse=True)
    m = len(pits)
    none = np.full(g.k, -np.inf), np.zeros((0, 4))
    if m == 1:
        return none
    bottom = np.append(v[pits[:-1]], -np.inf)  # the outside (id k) sorts last
    a, b = g.forward_edges()
    la, lb = label[a], label[b]
    cross = la != lb
    a, b, la, lb = a[cross], b[cross], la[cross], lb[cross]
    lo, hi = np.minimum(la, lb), np.maximum(la, lb)
    w = np.maximum(v[a], v[b])
    key = lo.astype(np.int64) * m + hi
    order = np.lexsort((w, key))
    ks = key[order]
    first = order[np.r_[True, ks[1:] != ks[:-1]]]
    lo, hi, w, key = lo[first], hi[first], w[first], key[first]
    # scipy drops zero weights: shift the (exact) pass heights to >= 1 for the tree only.
    tree = minimum_spanning_tree(csr_matrix((w - w.min() + 1.0, (lo, hi)), shape=(m, m))).tocoo()
    tlo, thi = np.minimum(tree.row, tree.col), np.maximum(tree.row, tree.col)
    tw = w[np.searchsorted(key, tlo.astype(np.int64) * m + thi)]
    order = np.argsort(tw, kind="stable")
    tlo, thi, tw = tlo[order].tolist(), thi[order].tolist(), tw[order].tolist()

    # Union-find over basins in pass order; the component with the higher bottom dies.
    uf = list(range(m))
    comp_bottom = bottom.tolist()
    bottom_basin = list(range(m))
    tree_parent = np.arange(m)
    tree_val = np.full(m, -np.inf)
    events = []

    def find(x):
        while uf[x] != x:
            uf[x] = uf[uf[x]]
            x = uf[x]
        return x

    for i, j, level in zip(tlo, thi, tw):
        ri, rj = find(i), find(j)
        dying, surv = (ri, rj) if comp_bottom[ri] > comp_bottom[rj] else (rj, ri)
        depth = level - comp_bottom[dying]
        filled = depth <= threshold
        if depth > 0:
            events.append((pits[bottom_basin[dying]], level, depth, filled))
        uf[dying] = surv
        tree_parent[dying] = surv
        if filled:
            tree_val[dying] = level
    # A basin's level: the last (highest) qualifying merge along its chain of components.
    val, par = tree_val, tree_parent
    while True:
        val = np.maximum(val, val[par])
        nxt = par[par]
        if np.array_equal(nxt, par):
            break
        par = nxt
    ev = np.array(events, dtype=float).reshape(-1, 4)
    ev = ev[np.argsort(-ev[:, 2], kind="stable")]
    return val[label], ev


def resolve_flats(level, changed, g, eps_mm=EPS_MM):
    """Give flats that contain ``changed`` cells a tiny slope down to their outlet.

    A flat is a connected set of interior cells with no strictly lower
    neighbour. Each cell is raised by ``eps * (1 + d)``, ``d`` its step
    distance to the flat's outlet, with eps shrunk per flat so that the flat
    stays below every higher neighbour (no new pits or peaks appear).

    Returns
    -------
    out : (k,) float, the raised values
    unresolved : int, changed cells still without a strictly lower neighbour
    """
    vn = g.neighbour_values(level)
    flat = ~((vn < level[:, None]).any(axis=1) | g.boundary)
    fi = np.flatnonzero(flat)
    out = level.copy()
    if len(fi):
        local = np.full(g.k, -1, np.int64)
        local[fi] = np.arange(len(fi))
        a, b = g.forward_edges(flat)
        n = len(fi)
        graph = csr_matrix((np.ones(len(a)), (local[a], local[b])), shape=(n, n))
        ncomp, comp = connected_components(graph, directed=False)
        wanted = np.zeros(ncomp, bool)
        wanted[comp[changed[fi]]] = True
        nbf = g.nb[fi]
        nb_flat = np.where(nbf >= 0, flat[nbf], True)  # outside counts as "not an outlet"
        vf = vn[fi]
        outlet = ((vf <= level[fi, None]) & ~nb_flat).any(axis=1) & wanted[comp]
        if outlet.any():
            d = dijkstra(graph, directed=False, indices=np.flatnonzero(outlet),
                         unweighted=True, min_only=True)
            ok = np.isfinite(d) & wanted[comp]
            dmax = np.zeros(ncomp)
            np.maximum.at(dmax, comp[ok], d[ok])
            rise = np.where(vf > level[fi, None], vf - level[fi, None], np.inf).min(axis=1)
            gap = np.full(ncomp, np.inf)
            np.minimum.at(gap, comp, rise)
            eps_c = np.minimum(eps_mm, 0.5 * gap / (dmax + 2.0))
            out[fi[ok]] += eps_c[comp[ok]] * (1.0 + d[ok])
    vn = g.neighbour_values(out)
    drains = (vn < out[:, None]).any(axis=1) | g.boundary
    return out, int(np.count_nonzero(changed & ~drains))


def fill_depressions(z, max_depth_mm=np.inf, eps_mm=EPS_MM):
    """Fill closed depressions of a field up to ``max_depth_mm`` deep, with an epsilon slope.

    Parameters
    ----------
    z : (rows, cols) float, mm; NaN outside the footprint

    Returns
    -------
    filled : (rows, cols) float, mm
    info : dict with ``events`` ((e, 4): bottom cell id, spill level mm, depth mm,
        filled flag), ``grid`` (Grid), ``exact`` ((k,) filled values before the
        epsilon slope), ``unresolved`` (int)
    """
    fp = np.isfinite(z)
    g = Grid(fp)
    v = z[fp]
    level, events = merge_levels(v, g, max_depth_mm)
    exact = np.maximum(v, level)
    changed = exact > v
    out, unresolved = resolve_flats(exact, changed, g, eps_mm) if changed.any() else (exact, 0)
    filled = z.copy()
    filled[fp] = out
    return filled, {"events": events, "grid": g, "exact": exact, "unresolved": unresolved}


def _pieces(mask, structure):
    lab, n = ndimage.label(mask, structure=structure)
    if n == 0:
        return lab, n, np.zeros((0, 2)), np.zeros(0, int)
    idx = np.arange(1, n + 1)
    centres = np.array(ndimage.center_of_mass(mask, lab, idx)).reshape(-1, 2)
    sizes = ndimage.sum_labels(mask, lab, idx).astype(int)
    return lab, n, centres, sizes


def _where_mm(hf, rc):
    """(n, 2) fractional (row, col) -> (n, 2) x, y in mm."""
    return hf.xy(rc[:, 0], rc[:, 1])


def check_topology(hf):
    """Raise ``validate.disconnected`` / ``validate.holes`` unless the footprint is a disk."""
    fp = hf.footprint
    px2 = hf.pixel_mm ** 2
    # Pieces touching only at a corner pinch the sheet: count them apart (4-connectivity).
    _, n, centres, sizes = _pieces(fp, ndimage.generate_binary_structure(2, 1))
    if n > 1:
        order = np.argsort(-sizes)
        xy = _where_mm(hf, centres[order])
        listing = "; ".join("%.1f mm2 around x=%.1f, y=%.1f mm" % (sizes[i] * px2, p[0], p[1])
                            for i, p in zip(order[:5], xy[:5]))
        raise InvalidHeightField(
            "the footprint is %d separate pieces; the sheet must be one piece" % n,
            code="validate.disconnected", file=hf.source, where=listing,
            fix="print the pieces as separate inputs, or join them in the data",
            details={"pieces": int(n), "centres_mm": xy.tolist(),
                     "areas_mm2": (sizes[order] * px2).tolist()})
    # Background is 8-connected (the dual of the 4-connected footprint).
    pad = np.pad(~fp, 1, constant_values=True)
    lab, n, centres, sizes = _pieces(pad, np.ones((3, 3), bool))
    outside = lab[0, 0]
    holes = [i for i in range(n) if i + 1 != outside]
    if holes:
        xy = _where_mm(hf, centres[holes] - 1.0)
        listing = "; ".join("%.1f mm2 at x=%.1f, y=%.1f mm" % (sizes[i] * px2, p[0], p[1])
                            for i, p in zip(holes[:5], xy[:5]))
        raise InvalidHeightField(
            "the footprint has %d interior hole%s; the sheet must be a disk (no holes)"
            % (len(holes), "" if len(holes) == 1 else "s"), code="validate.holes",
            file=hf.source, where=listing,
            fix="fill the holes with heights (interpolate missing data) or cut the footprint "
                "so each hole opens to the edge",
            details={"holes": len(holes), "centres_mm": xy.tolist(),
                     "areas_mm2": [float(sizes[i] * px2) for i in holes]})


def longest_diameter_mm(hf):
    """Largest distance between two footprint sample points, mm."""
    g = Grid(hf.footprint)
    pts = hf.xy(g.rows[g.boundary], g.cols[g.boundary])
    try:
        pts = pts[ConvexHull(pts).vertices]
    except (QhullError, ValueError):  # a line or a point: all boundary points are extreme
        pass
    d2 = ((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1)
    return float(np.sqrt(d2.max()))


def check_fits_bed(extent_mm, bed_mm, allow_rotation=True, file=None, what="the part"):
    """Raise ``validate.too_large`` unless an ``extent_mm`` (w, h) box fits ``bed_mm`` (x, y).

    Returns dict ``rotated`` (bool: fits only turned 90 degrees) and
    ``margin_mm`` (smallest free margin, mm).
    """
    w, h = (float(e) for e in extent_mm)
    bx, by = (float(b) for b in bed_mm)
    straight = max(w - bx, h - by)
    turned = max(w - by, h - bx) if allow_rotation else np.inf
    over = min(straight, turned)
    if over > 0:
        raise PlanError(
            "%s is %.1f x %.1f mm and does not fit the %.0f x %.0f mm bed: it overhangs by "
            "%.1f mm%s" % (what, w, h, bx, by, over, " even turned 90 degrees" if allow_rotation
                           else ""),
            code="validate.too_large", file=file, where="extent %.1f x %.1f mm" % (w, h),
            fix="scale it down (size_mm or pixel_mm in the sidecar) or use a printer profile "
                "with a larger bed", details={"overhang_mm": over, "extent_mm": [w, h],
                                              "bed_mm": [bx, by]})
    return {"rotated": bool(turned < straight), "margin_mm": float(-over)}


def _sidecar_name(source):
    """The sidecar a person would edit for input ``source``: ``NAME.yaml`` beside it."""
    return Path(source).stem + ".yaml" if source else "NAME.yaml"


def validate(hf, max_fill_mm, bed_mm=None, eps_mm=EPS_MM):
    """Check disk topology, fill shallow depressions, refuse deep ones, check the bed.

    Parameters
    ----------
    hf : HeightField
    max_fill_mm : float
        Deepest closed depression that is filled; deeper ones raise
        ``validate.depression``.
    bed_mm : (2,) float, optional
        If given, the footprint's bounding box must fit (``validate.too_large``).

    Returns
    -------
    hf : HeightField, depressions filled (filled flats sloped by ~eps_mm per cell)
    report : dict ``filled_pits``, ``filled_volume_mm3``, ``deepest_fill_mm``,
        ``longest_diameter_mm``, ``max_height_mm``, ``filled`` (up to 50
        {x_mm, y_mm, depth_mm}), ``epsilon_raise_mm``, ``unresolved_flat_cells``
    """
    check_topology(hf)
    fp = hf.footprint
    if bed_mm is not None:
        r, c = np.nonzero(fp)
        extent = (np.ptp(c) * hf.pixel_mm, np.ptp(r) * hf.pixel_mm)
        check_fits_bed(extent, bed_mm, file=hf.source, what="the footprint")
    filled, info = fill_depressions(hf.z, np.inf, eps_mm)
    g, ev = info["grid"], info["events"]
    v = hf.z[fp]
    deep = ev[ev[:, 2] > max_fill_mm + 1e-9]
    if len(deep):
        cells = deep[:, 0].astype(int)
        xy = hf.xy(g.rows[cells], g.cols[cells])
        listing = "; ".join("%.2f mm deep at x=%.1f, y=%.1f mm" % (d, p[0], p[1])
                            for d, p in zip(deep[:5, 2], xy[:5]))
        raise InvalidHeightField(
            "%d closed depression%s deeper than max_fill_mm = %g mm (deepest %.2f mm); the "
            "sheet pops up one way and cannot form a bowl or crater"
            % (len(deep), "" if len(deep) == 1 else "s", max_fill_mm, deep[0, 2]),
            code="validate.depression", file=hf.source, where=listing,
            fix="raise max_fill_mm (in the sidecar %s or the profile's validate section) to "
                "fill it, e.g. `max_fill_mm: %.1f`, or edit the data" % (
                    _sidecar_name(hf.source), np.ceil(deep[0, 2] * 10 + 1) / 10),
            details={"depressions": [{"x_mm": float(p[0]), "y_mm": float(p[1]),
                                      "depth_mm": float(d), "spill_mm": float(s)}
                                     for p, d, s in zip(xy[:50], deep[:50, 2], deep[:50, 1])],
                     "max_fill_mm": max_fill_mm})
    exact = info["exact"]
    fill = exact - v
    grid_fill = np.zeros(fp.shape)
    grid_fill[fp] = fill
    _, n_pits = ndimage.label(grid_fill > 0, structure=np.ones((3, 3), bool))
    cells = ev[:, 0].astype(int)
    xy = hf.xy(g.rows[cells], g.cols[cells])
    report = {
        "filled_pits": int(n_pits),
        "filled_volume_mm3": float(fill.sum() * hf.pixel_mm ** 2),
        "deepest_fill_mm": float(fill.max(initial=0.0)),
        "longest_diameter_mm": longest_diameter_mm(hf),
        "max_height_mm": float(np.nanmax(filled)),
        "filled": [{"x_mm": float(p[0]), "y_mm": float(p[1]), "depth_mm": float(d)}
                   for p, d in zip(xy[:50], ev[:50, 2])],
        "epsilon_raise_mm": float((filled[fp] - exact).max(initial=0.0)),
        "unresolved_flat_cells": info["unresolved"],
    }
    return HeightField(filled, hf.pixel_mm, color=hf.color, source=hf.source), report
