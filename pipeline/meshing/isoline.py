"""Isoline / gradient-line graph and its triangle mesh (paper 6.1).

1. Equidistant isolines of the guide field (``pipeline.meshing.contours``), clipped to
   the footprint; the outline itself is the lowest isoline when the footprint
   edge is level (a dome, an island), else a boundary on which open isoline
   arcs end (a tile cut from a map).
2. Gradient lines, band by band: seeds on each isoline (the ends of the lines
   that arrived from below, plus new seeds where lines diverge) are traced up
   to the next isoline (``pipeline.meshing.gradient``); an isoline no line reached gets
   lines traced down from it. Their intersections with the isolines are the
   graph's nodes; edges run along isolines or gradient lines.
3. The graph's cells (faces of the planar graph, found from the rotation
   system) are triangulated: cells between two isolines are zipped by the
   shortest diagonal after upsampling isoline edges to ``l_u``; peak and saddle
   polygons are fanned around an inserted centre vertex
   (``pipeline.meshing.triangulate``).
4. Optionally the same cells again with fewer isoline vertices: the coarser
   sheet the forward simulation can run on (``Mesh.sheet``).
"""

import numpy as np
import shapely

from pipeline.errors import MeshingError
from pipeline.geometry import Mesh, SimSheet, signed_areas_2d, unique_edges
from pipeline.meshing.gradient import Snapper, trace
from pipeline.meshing.contours import GuideField, Piece, footprint_outline, isoline_pieces, points_at
from pipeline.meshing.triangulate import (cell_rings, drop_degenerate, ear_clip, fan,
                                          main_runs, pull_inside, run_keys, run_level,
                                          sim_sheet, split_arcs, split_ring, trace_faces,
                                          zip_strips)


# Points along an isoline no gradient line reached from which a straight bridge down
# is tried (the nearest that crosses nothing is taken).
CONNECTOR_TRIES = 16


def build_mesh(hf, isoline_step_mm=1.0, gradient_spacing_mm=2.0, l_u_mm=0.25,
               flat_slope=0.05, l_sim_mm=0.0):
    """Mesh a validated height field.

    Parameters
    ----------
    hf : HeightField, NaN outside the footprint, no closed depressions
    isoline_step_mm : float, height between isolines
    gradient_spacing_mm : float, spacing of gradient lines along an isoline
    l_u_mm : float, longest printing edge (the paper's l_u)
    flat_slope : float, ramp of the guide field in flat areas (see isolines)
    l_sim_mm : float, longest isoline edge of the coarser sheet the forward
        simulation runs on (``Mesh.sheet``); 0 gives no coarse sheet

    Returns
    -------
    Mesh
    """
    field = GuideField(hf, flat_slope=flat_slope)
    graph = _Graph(field, isoline_step_mm, gradient_spacing_mm, l_u_mm, l_sim_mm)
    graph.trace_bands()
    return graph.triangulate()


class _Graph:
    def __init__(self, field, dh, d_g, l_u, l_sim=0.0):
        self.field, self.dh, self.d_g, self.l_u = field, dh, d_g, l_u
        self.l_sim = float(l_sim)
        outline_pts, self.polygon = footprint_outline(field, min(l_u, field.pixel_mm))
        g_out = field.value(outline_pts)
        g_in = field.g[field.inside]
        self.level_outline = bool(np.ptp(g_out) < dh)
        if self.level_outline:
            base = float(g_out.max())
            levels = base + dh * np.arange(1, int((g_in.max() - base) / dh) + 1)
            self.levels = np.concatenate([[float(g_out.mean())], levels])
        else:
            base = float(g_in.min())
            self.levels = base + dh * np.arange(1, int((g_in.max() - base) / dh) + 1)
        self.levels = self.levels[self.levels < g_in.max() - 0.02 * dh]
        if len(self.levels) < 1:
            raise MeshingError("the height field is too flat to have isolines %.3g mm apart" % dh,
                               code="mesh.too_flat",
                               fix="lower mesh.isoline_step_mm or raise height_mm")
        outline = Piece(outline_pts, True, self.levels[0] if self.level_outline else np.nan,
                        "outline")
        iso_levels = self.levels[1:] if self.level_outline else self.levels
        self.pieces = [outline] + isoline_pieces(field, self.polygon, iso_levels, 2 * l_u)
        if len(self.pieces) < 2:
            raise MeshingError(
                "after simplification the shape has no isoline %.3g mm above its edge "
                "(highest point %.3g mm): nothing for the sheet to form"
                % (dh, float(g_in.max() - g_out.min())), code="mesh.too_flat",
                fix="make the part taller (height_mm in the sidecar), or lower "
                    "mesh.isoline_step_mm or min_prominence_mm")
        self.level_index = np.array(
            [-1 if np.isnan(p.level) else int(np.argmin(np.abs(self.levels - p.level)))
             for p in self.pieces])
        self.node_xy = []
        self.piece_n = [[] for _ in self.pieces]   # per piece: node ids
        # Per piece, the arc-length t of its nodes in an array grown by doubling
        # (add_node searches it often); the first len(piece_n[pid]) entries are set.
        self._t_buf = [np.empty(16) for _ in self.pieces]
        self.bridges = []
        self.connectors = 0
        self._outline_snap = Snapper(self.pieces, [0])
        for pid, pc in enumerate(self.pieces):
            if pc.kind == "iso" and not pc.closed:
                for end, t in ((pc.points[0], 0.0), (pc.points[-1], pc.length)):
                    node = self.add_node(pid, t, xy=end)
                    _, t_out, _ = self._outline_snap.snap(end[None])
                    self.add_node(0, float(t_out[0]), node=node)

    # -- nodes -------------------------------------------------------------
    def add_node(self, pid, t, xy=None, node=None, merge_mm=None):
        """Put a node on piece ``pid`` at ``t``; reuse one within ``merge_mm``."""
        pc = self.pieces[pid]
        merge_mm = 0.5 * self.l_u if merge_mm is None else merge_mm
        count = len(self.piece_n[pid])
        if count and node is None:
            d = np.abs(self._t_buf[pid][:count] - t)
            if pc.closed:
                np.minimum(d, pc.length - d, out=d)
            k = int(d.argmin())
            if d[k] < merge_mm:
                return self.piece_n[pid][k]
        if node is None:
            node = len(self.node_xy)
            self.node_xy.append(pc.at([t])[0] if xy is None else np.asarray(xy, float))
        if count == len(self._t_buf[pid]):
            self._t_buf[pid] = np.concatenate([self._t_buf[pid], np.empty(count)])
        self._t_buf[pid][count] = t
        self.piece_n[pid].append(node)
        return node

    def piece_t(self, pid):
        """Arc-length parameters of piece ``pid``'s nodes, mm ((k,) float, in insertion order)."""
        return self._t_buf[pid][:len(self.piece_n[pid])]

    def _seeds(self, pid):
        """Seed parameters on a piece: its nodes thinned to ~d_g, gaps filled."""
        pc = self.pieces[pid]
        ts = np.sort(self.piece_t(pid))
        d_g = self.d_g
        if pc.closed and len(ts) == 0:
            n = max(1, int(round(pc.length / d_g)))
            return list(np.arange(n) * pc.length / n)
        kept = []
        for t in ts:
            if pc.kind == "iso" and not pc.closed and (t < 1e-9 or t > pc.length - 1e-9):
                continue  # an arc's ends lie on the outline: lines from there leave the part
            if not kept or t - kept[-1] >= 0.5 * d_g:
                kept.append(t)
        # Gaps to fill: between kept seeds, and (open pieces) from the ends.
        if pc.closed:
            bounds = kept + [kept[0] + pc.length] if kept else []
        else:
            bounds = [0.0] + kept + [pc.length]
        seeds = list(kept)
        for a, b in zip(bounds[:-1], bounds[1:]):
            gap = b - a
            n = int(round(gap / d_g))
            if n >= 2 or (not pc.closed and (a == 0.0 or b == pc.length) and gap > d_g):
                n = max(n, 2)
                inner = a + gap * np.arange(1, n) / n
                if not pc.closed:
                    inner = inner[(inner > 0.25 * d_g) & (inner < pc.length - 0.25 * d_g)]
                seeds.extend(np.mod(inner, pc.length) if pc.closed else inner)
        return seeds

    # -- gradient lines ----------------------------------------------------
    def trace_bands(self):
        li_of = self.level_index
        by_level = [np.nonzero(li_of == li)[0] for li in range(len(self.levels))]
        snappers = [Snapper(self.pieces, ids) for ids in by_level]
        # Short segments, not whole loops: a loop's box covers everything inside it.
        segs = np.concatenate([np.stack([p._path[:-1], p._path[1:]], axis=1)
                               for p in self.pieces])
        self._piece_tree = shapely.STRtree(shapely.linestrings(segs))
        self._bridge_lines = []   # every bridge so far, shrunk (see _planar)
        tol = 1.5 * self.field.pixel_mm
        if not self.level_outline:
            self._trace_from_sloped_outline(snappers, tol)
        for li in range(len(self.levels) - 1):
            src, t_src = [], []
            for pid in by_level[li]:
                for t in self._seeds(pid):
                    src.append(pid)
                    t_src.append(t)
            self._connect(src, t_src, self.levels[li + 1], snappers[li + 1], tol)
            # Isolines no line reached (a new peak past a saddle): trace down from them.
            orphans = [pid for pid in by_level[li + 1] if not self.piece_n[pid]]
            src, t_src = [], []
            for pid in orphans:
                for t in self._seeds(pid):
                    src.append(pid)
                    t_src.append(t)
            self._connect(src, t_src, self.levels[li], snappers[li], tol)
            for pid in orphans:
                if not self.piece_n[pid]:
                    self._straight_connector(pid, snappers[li])
        self._join_islands(snappers)

    def _join_islands(self, snappers, rounds=4):
        """Bridge down every group of isolines joined to one another but not to the
        outline (a closed isoline at the outline's own level, and what rises from it,
        which no band's gradient lines leave downward): the graph's cells around such a
        group were triangulated twice, once with it and once without. Each group's
        lowest isoline is bridged to the level below where a straight bridge crosses
        nothing, else to the nearest isoline outside the group it can reach."""
        for _ in range(rounds):
            groups = self._islands()
            if not groups:
                return
            for members in groups:
                pid = min(members, key=lambda q: self.level_index[q])
                li = int(self.level_index[pid])
                below = snappers[li - 1] if li > 0 else self._outline_snap
                outside = [q for q in range(len(self.pieces)) if q not in members]
                self._straight_connector(pid, below, others=outside)

    def _islands(self):
        """Groups of isolines with nodes that no bridge or shared node joins to the
        outline: list of sets of piece ids."""
        parent = list(range(len(self.pieces)))

        def root(x):
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        owner = {}
        for pid, nodes in enumerate(self.piece_n):
            for nd in nodes:
                parent[root(pid)] = root(owner.setdefault(nd, pid))
        for a, b in self.bridges:
            parent[root(owner[a])] = root(owner[b])
        groups = {}
        for pid, nodes in enumerate(self.piece_n):
            if nodes and root(pid) != root(0):
                groups.setdefault(root(pid), set()).add(pid)
        return list(groups.values())

    def _connect(self, src, t_src, level, snapper, tol):
        if not src:
            return
        src = np.asarray(src)
        t_src = np.asarray(t_src, float)
        xy0 = points_at(self.pieces, src, t_src)
        xy1, ok = trace(self.field, xy0, level)
        pid1, t1, dist = snapper.snap(xy1)
        ok &= (pid1 >= 0) & (dist < tol)
        src, t_src, pid1, t1, xy0 = src[ok], t_src[ok], pid1[ok], t1[ok], xy0[ok]
        keep = self._non_crossing(src, t_src, pid1, t1)
        src, t_src, pid1, t1, xy0 = src[keep], t_src[keep], pid1[keep], t1[keep], xy0[keep]
        xy1 = points_at(self.pieces, pid1, t1)
        keep = self._planar(xy0, xy1)
        pairs = []
        # The end points are known already: a new node needs no second look-up on its piece.
        for a, ta, b, tb, p, q in zip(src[keep], t_src[keep], pid1[keep], t1[keep],
                                      xy0[keep], xy1[keep]):
            na = self.add_node(int(a), float(ta), xy=p)
            nb = self.add_node(int(b), float(tb), xy=q)
            if na != nb:
                pairs.append((na, nb))
        self._add_bridges(self._still_planar(pairs))

    def _still_planar(self, pairs):
        """The node pairs whose bridge still crosses nothing: a new end within merging
        distance of a node reuses that node, which moves the bridge (near where an
        isoline meets the outline, across it)."""
        if not pairs:
            return pairs
        a = np.array([self.node_xy[na] for na, _ in pairs], float)
        b = np.array([self.node_xy[nb] for _, nb in pairs], float)
        return [p for p, keep in zip(pairs, self._planar(a, b)) if keep]

    def _add_bridges(self, pairs):
        """Join node pairs ((na, nb), ...) by bridges."""
        if not pairs:
            return
        self.bridges.extend(pairs)
        a = np.array([self.node_xy[na] for na, _ in pairs], float)
        b = np.array([self.node_xy[nb] for _, nb in pairs], float)
        self._bridge_lines.extend(_shrunk_many(a, b))

    def _planar(self, xy0, xy1):
        """Keep the straight bridges that cross no isoline, no earlier bridge and no
        shorter bridge of this batch: the graph must stay planar for its cells."""
        if len(xy0) == 0:
            return np.zeros(0, bool)
        lines = _shrunk_many(xy0, xy1)
        ok = np.ones(len(lines), bool)
        hit, _ = self._piece_tree.query(lines, predicate="intersects")
        ok[hit] = False
        # Against every bridge, not only those of the band being traced: a connector
        # that found no way down joins whatever isoline it can reach, in another band
        # (seed 147 of the random terrains: one to the level above, crossed later by a
        # gradient line of that band), and a group's bridge to the outline can pass
        # through any band.
        if self._bridge_lines:
            hit, _ = shapely.STRtree(self._bridge_lines).query(lines, predicate="intersects")
            ok[hit] = False
        cand = np.nonzero(ok)[0]
        if len(cand) > 1:
            tree = shapely.STRtree(lines[cand])
            a, b = tree.query(lines[cand], predicate="intersects")
            pairs = a != b
            partners = [[] for _ in cand]
            for i, j in zip(a[pairs], b[pairs]):
                partners[i].append(j)
            length = np.linalg.norm(xy1[cand] - xy0[cand], axis=1)
            accepted = np.zeros(len(cand), bool)
            for i in np.argsort(length):
                if not any(accepted[j] for j in partners[i]):
                    accepted[i] = True
            ok[cand[~accepted]] = False
        return ok

    def _non_crossing(self, pa, ta, pb, tb):
        """Drop lines whose order on the far isoline reverses their order on the near one."""
        keep = np.ones(len(pa), bool)
        for key in set(zip(pa.tolist(), pb.tolist())):
            sel = np.nonzero((pa == key[0]) & (pb == key[1]))[0]
            sel = sel[np.argsort(ta[sel])]
            far = self.pieces[key[1]]
            last = None
            for k in sel:
                if last is not None:
                    step = tb[k] - last
                    if far.closed:
                        step = np.mod(step, far.length)
                        if step > 0.5 * far.length:
                            keep[k] = False
                            continue
                    elif step < 0:
                        keep[k] = False
                        continue
                last = tb[k]
        return keep

    def _trace_from_sloped_outline(self, snappers, tol):
        outline = self.pieces[0]
        n = max(1, int(round(outline.length / self.d_g)))
        t = np.arange(n) * outline.length / n
        xy = outline.at(t)
        g = self.field.value(xy)
        li = np.searchsorted(self.levels, g + 0.1 * self.dh)
        for k in np.unique(li[li < len(self.levels)]):
            sel = np.nonzero(li == k)[0]
            self._connect([0] * len(sel), t[sel], self.levels[k], snappers[k], tol)

    def _straight_connector(self, pid, snapper, others=None):
        """Join an isoline no gradient line reached to the level below by a straight
        bridge, from the point along it nearest that level among those whose bridge
        crosses no isoline or bridge (one that crosses makes a cell overlap itself).
        Where every way down crosses one (a small peak behind a fold of the level
        below), to the nearest isoline it can reach (of ``others``: default, all but
        itself); from its start where none is clear."""
        pc = self.pieces[pid]
        t = np.linspace(0.0, pc.length, CONNECTOR_TRIES, endpoint=not pc.closed)
        xy0 = pc.at(t)
        pb, tb, dist = snapper.snap(xy0)
        if (pb < 0).all():
            pb, tb, dist = self._outline_snap.snap(xy0)
        k = self._clearest(xy0, pb, tb, dist)
        if k is None:
            if others is None:
                others = [q for q in range(len(self.pieces)) if q != pid]
            qb, qt, qd = Snapper(self.pieces, others).snap(xy0)
            k = self._clearest(xy0, qb, qt, qd)
            if k is not None:
                pb, tb = qb, qt
        k = 0 if k is None else k
        na = self.add_node(pid, float(t[k]))
        nb = self.add_node(int(pb[k]), float(tb[k]))
        self._add_bridges([(na, nb)])
        self.connectors += 1

    def _clearest(self, xy0, pb, tb, dist):
        """Of straight bridges from ``xy0`` to the points ``tb`` on pieces ``pb`` (-1:
        none), the shortest that crosses nothing: its index, or None."""
        ok = np.flatnonzero(pb >= 0)
        if not len(ok):
            return None
        clear = ok[self._planar(xy0[ok], points_at(self.pieces, pb[ok], tb[ok]))]
        return int(clear[np.argmin(dist[clear])]) if len(clear) else None

    # -- triangulation -----------------------------------------------------
    def triangulate(self):
        n_verts = len(self.node_xy)
        verts = [np.asarray(self.node_xy, float).reshape(-1, 2)]   # blocks, in vertex id order
        node_level = np.full(n_verts, np.nan)
        level_blocks = []  # per piece, the level of its inserted vertices
        he = []            # (from node, to node, piece, vertex list) per half-edge
        printing = []      # (k, 3) blocks of (a, b, isoline id)
        self.arcs = []     # (vertex chain from node to node, length mm) along pieces
        outline = None     # the outline's vertex ids, counter-clockwise
        iso_id = {}
        for pid, pc in enumerate(self.pieces):
            if not self.piece_n[pid]:
                continue
            is_print = not np.isnan(pc.level)
            if is_print:
                iso_id[pid] = len(iso_id)
            order = np.argsort(self.piece_t(pid))
            ts = self.piece_t(pid)[order]
            ns = np.asarray(self.piece_n[pid])[order]
            t_in, seq, pos, lengths = split_arcs(ts, ns, pc.length if pc.closed else None,
                                                 self.l_u, n_verts)
            if not len(lengths):
                continue
            n_verts += len(t_in)
            verts.append(pc.at(t_in))
            level_blocks.append(np.full(len(t_in), pc.level))
            if pc.kind == "outline":
                outline = seq[:-1]
            if is_print:
                node_level[ns] = pc.level
                printing.append(np.column_stack([seq[:-1], seq[1:],
                                                 np.full(len(seq) - 1, iso_id[pid])]))
            sl, pl = seq.tolist(), pos.tolist()
            for k in range(len(lengths)):
                chain = sl[pl[k]:pl[k + 1] + 1]
                self.arcs.append((seq[pl[k]:pl[k + 1] + 1], lengths[k]))
                he.append((chain[0], chain[-1], pid, chain[:-1]))
                he.append((chain[-1], chain[0], pid, chain[:0:-1]))
        for a, b in self.bridges:
            he.append((a, b, -1, [a]))
            he.append((b, a, -1, [b]))
        xy = np.concatenate(verts)
        if outline is not None:
            # The outline's new chords cut its bends: an isoline nearly tangent to it
            # may now lie just outside.
            xy = pull_inside(xy, outline, self.polygon.exterior)
        faces_he = trace_faces(xy, he)
        printing = np.concatenate(printing) if printing else np.zeros((0, 3), np.int64)
        return self._assemble(xy, np.concatenate([node_level] + level_blocks), he, faces_he,
                              printing, iso_id)

    def _assemble(self, xy, level, he, faces_he, printing, iso_id):
        field = self.field
        z = field.height(xy)
        points3 = np.column_stack([xy, z])
        lowers, uppers, zip_rings, extra_tris = [], [], [], []
        centres = []
        fans = []   # (ring, centre id) of fanned cells; ear-clipped cells have no centre
        peaks = saddles = 0
        key = run_keys(he, self.pieces)
        rings, offsets, is_cell = cell_rings(xy, he, faces_he)
        for cycle, ring, offs, cell in zip(faces_he, rings, offsets, is_cell):
            if not cell:
                continue  # the outer face
            runs = main_runs([key[h] for h in cycle])
            if len(runs) == 2 and run_level(runs[0], cycle, he, self.pieces) != \
                    run_level(runs[1], cycle, he, self.pieces):
                lo, up = sorted(runs, key=lambda r: run_level(r, cycle, he, self.pieces))
                lower, upper = split_ring(ring, offs, up)
                lowers.append(lower)
                uppers.append(upper)
                zip_rings.append(ring)
                continue
            if len(runs) == 1 and len(runs[0]) < len(cycle):
                lower, upper = split_ring(ring, offs, runs[0], swap=True)
                if len(upper) == 1:
                    lowers.append(lower)
                    uppers.append(upper)
                    zip_rings.append(ring)
                    continue
            cap = len(runs) == 1 and len(runs[0]) == len(cycle)
            peaks += cap
            # A saddle joins two or more closed isolines of one level; cells between
            # open arcs (where isolines meet the edge) are not saddles of the field.
            saddles += (not cap) and len(runs) >= 2 and all(
                self.pieces[he[cycle[r[0]]][2]].closed for r in runs)
            centre = _peak(field, xy[ring]) if cap else _inner_point(xy[ring])
            cid = len(xy) + len(centres)
            tris = fan(xy, ring, cid, centre)
            if tris is None:
                tris = ear_clip(xy, ring)
                fans.append((ring, -1))
            else:
                centres.append(centre)
                fans.append((ring, cid))
            extra_tris.append(tris)
        if centres:
            c = np.asarray(centres)
            xy = np.vstack([xy, c])
            points3 = np.vstack([points3, np.column_stack([c, field.height(c)])])
            level = np.concatenate([level, field.value(c)])
        zipped, strip = zip_strips(points3, lowers, uppers)
        # A strip that folds (a strongly bent cell) is ear-clipped instead.
        folded = np.unique(strip[signed_areas_2d(xy, zipped) <= 0])
        if len(folded):
            zipped = zipped[~np.isin(strip, folded)]
            extra_tris.extend(ear_clip(xy, zip_rings[k]) for k in folded)
        faces = np.concatenate([zipped] + extra_tris)
        faces = drop_degenerate(faces)
        nan = np.isnan(level)
        level[nan] = field.value(xy[nan])
        sheet = None
        if self.l_sim > 0:
            sheet = sim_sheet(points3, len(self.node_xy), len(xy) - len(centres), self.arcs,
                              self.bridges, (lowers, uppers, zip_rings), fans, self.l_sim)
        return _make_mesh(points3, faces, printing, level, self, iso_id,
                          {"peaks": int(peaks), "saddles": int(saddles),
                           "connectors": int(self.connectors),
                           "level_outline": self.level_outline}, sheet)


def _shrunk_many(a, b, eps_mm=1e-4):
    """The segments a-b ((q, 2) end points, mm) minus a sliver at each end, so touching
    ends don't intersect: (q,) LineStrings."""
    d = b - a
    n = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    e = np.minimum(eps_mm / n, 0.25)[:, None]
    return shapely.linestrings(np.stack([a + e * d, b - e * d], axis=1))


def _peak(field, ring_xy):
    """Highest grid point of the guide field inside a closed isoline."""
    poly = shapely.Polygon(ring_xy)
    x0, y0, x1, y1 = poly.bounds
    p = field.pixel_mm
    xs = np.arange(np.floor(x0 / p), np.ceil(x1 / p) + 1) * p
    ys = np.arange(np.floor(y0 / p), np.ceil(y1 / p) + 1) * p
    X, Y = np.meshgrid(xs, ys)
    inside = shapely.contains_xy(poly, X.ravel(), Y.ravel())
    if not inside.any():
        return _inner_point(ring_xy)
    cand = np.column_stack([X.ravel()[inside], Y.ravel()[inside]])
    return cand[int(np.argmax(field.value(cand)))]


def _inner_point(ring_xy):
    poly = shapely.Polygon(ring_xy)
    c = poly.centroid
    if not poly.contains(c):
        c = poly.point_on_surface()
    return np.array([c.x, c.y])


def refuse_overlap(points3, edges, shared):
    """Raise MeshingError ``mesh.overlap`` where an edge ((e, 2) int) is shared by more
    than two faces (``shared`` (e,) int): cells overlap, and nothing after meshing can
    work on such a sheet (a fault of the mesher, told as one rather than a crash)."""
    if not (shared > 2).any():
        return
    bad = edges[shared > 2]
    x, y = points3[bad[0], :2].mean(axis=0)
    raise MeshingError(
        "the mesher made overlapping triangles (%d edges shared by more than two), a fault "
        "of hostd's mesher on this shape" % len(bad), code="mesh.overlap",
        where="x %.1f mm, y %.1f mm" % (x, y),
        fix="the file is not at fault: report it (with its sidecar) so the mesher can be "
            "fixed")


def _make_mesh(points3, faces, printing, level, graph, iso_id, info, sheet=None):
    faces = np.asarray(faces, dtype=np.int64)
    used = np.zeros(len(points3), bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    faces = remap[faces]
    points3 = points3[used]
    level = level[used]
    if sheet is not None:
        ok = used[sheet.dropped]
        sheet = SimSheet(faces=remap[sheet.faces], dropped=remap[sheet.dropped[ok]],
                         between=remap[sheet.between[ok]], t=sheet.t[ok])
    flipped = signed_areas_2d(points3, faces) <= 0
    edges, shared = unique_edges(faces, return_counts=True)
    refuse_overlap(points3, edges, shared)
    pr = np.asarray(printing, dtype=np.int64).reshape(-1, 3)
    pr = pr[used[pr[:, 0]] & used[pr[:, 1]]]
    pe = np.sort(remap[pr[:, :2]], axis=1)
    n = len(points3)
    key_e = edges[:, 0] * n + edges[:, 1]
    key_p, first = np.unique(pe[:, 0] * n + pe[:, 1], return_index=True)
    is_print = np.isin(key_e, key_p)
    printing_edges = edges[is_print]
    pos = np.searchsorted(key_p, key_e[is_print])
    printing_isoline = pr[first[pos], 2]
    ids = sorted(iso_id, key=iso_id.get)
    info = dict(info)
    info.update({"isolines": len(ids), "flipped_faces": int(flipped.sum()),
                 "open_isolines": int(sum(not graph.pieces[p].closed for p in ids))})
    return Mesh(vertices=points3, faces=faces, printing_edges=printing_edges,
                bridge_edges=edges[~is_print], vertex_level=level,
                printing_isoline=printing_isoline,
                isoline_level=np.array([graph.pieces[p].level for p in ids]),
                isoline_closed=np.array([graph.pieces[p].closed for p in ids]),
                info=info, sheet=sheet)
