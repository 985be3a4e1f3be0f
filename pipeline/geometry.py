"""Mesh container and small vectorised geometry helpers shared by the stages.

Conventions: millimetres; faces counter-clockwise seen from +z on the target
surface; every unique face edge is either a printing edge (along an isoline)
or a bridge edge (everything else).
"""

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Mesh:
    """Triangle mesh of the target surface, with the paper's edge classes.

    Attributes
    ----------
    vertices : (n, 3) float, mm
    faces : (m, 3) int
    printing_edges : (p, 2) int
        Edges along isolines (the printing direction), sorted vertex pairs.
    bridge_edges : (b, 2) int
        All other edges (along gradient lines, diagonals, fans), sorted pairs.
    vertex_level : (n,) float, mm
        Isoline value per vertex: the height of the isoline it lies on; for
        inserted centre and boundary vertices, their own height.
    printing_isoline : (p,) int
        Isoline id of each printing edge (index into ``isoline_level``).
    isoline_level : (k,) float, mm
        Height of each isoline piece.
    isoline_closed : (k,) bool
        True for closed loops, False for open arcs ending on the boundary.
    info : dict
        Counts for the report (``isolines``, ``saddles``, ``peaks``, ...).
    sheet : SimSheet or None
        A coarser triangulation of the same sheet for the forward simulation.
    """

    vertices: np.ndarray
    faces: np.ndarray
    printing_edges: np.ndarray
    bridge_edges: np.ndarray
    vertex_level: np.ndarray
    printing_isoline: np.ndarray
    isoline_level: np.ndarray = field(default_factory=lambda: np.zeros(0))
    isoline_closed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    info: dict = field(default_factory=dict)
    sheet: "SimSheet" = None


@dataclass
class SimSheet:
    """The sheet at a coarser resolution: same cells, fewer isoline vertices.

    The printing edges are upsampled to ``l_u`` for the tool paths; the sheet's
    mechanics do not need that resolution, and the forward simulation's cost
    grows with it. Every dropped vertex lies on an isoline (or outline) arc
    between two kept ones, so the coarse result gives it a position.

    Attributes
    ----------
    faces : (mc, 3) int
        Triangles over a subset of the mesh's vertices, counter-clockwise.
    dropped : (k,) int
        Mesh vertices that are in no coarse face.
    between : (k, 2) int
        The kept vertices on either side of each dropped one, along its arc.
    t : (k,) float
        Position of each dropped vertex between them (0-1, by arc length).
    """

    faces: np.ndarray
    dropped: np.ndarray
    between: np.ndarray
    t: np.ndarray


def quarter_turn(d):
    """Directions ``d`` ((m, 2)) turned a quarter counter-clockwise: across them, (m, 2)."""
    d = np.asarray(d, dtype=float)
    return np.stack([-d[:, 1], d[:, 0]], axis=1)


def on_bed(xy, bed_mm):
    """Bed coordinates of a layout ``xy`` ((n, 2) mm): its bounding box centred on a bed
    of ``bed_mm`` (width, depth), so the tool paths, the G-code and the screen-print
    marks all share one frame."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return xy - (lo + hi) / 2.0 + np.asarray(bed_mm, float) / 2.0


def unique_edges(faces, return_counts=False):
    """Unique undirected edges of a triangle mesh.

    Parameters
    ----------
    faces : (m, 3) int
    return_counts : bool
        Also return how many faces share each edge.

    Returns
    -------
    edges : (e, 2) int, sorted pairs, lexicographically sorted rows
    counts : (e,) int, with ``return_counts``
    """
    sides, edges = face_sides(faces)
    return (edges, np.bincount(sides.ravel(), minlength=len(edges))) if return_counts else edges


def face_sides(faces):
    """Each triangle's sides numbered as :func:`unique_edges` numbers the edges.

    Returns (sides (m, 3) int: the edge of side k, from corner k to corner k + 1, edges
    (e, 2) int as :func:`unique_edges`)."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    n = int(f.max(initial=0)) + 1
    nxt = np.roll(f, -1, axis=1)
    # One int64 key per side, sorted once: far faster than unique(axis=0). A mesh's keys
    # come in long sorted runs, which the stable sort (timsort) orders in a fifth of
    # quicksort's time.
    key = (np.minimum(f, nxt) * n + np.maximum(f, nxt)).ravel()
    order = np.argsort(key, kind="stable")
    first = np.ones(len(key), bool)
    first[1:] = key[order[1:]] != key[order[:-1]]
    sides = np.empty(len(key), np.int64)
    sides[order] = np.cumsum(first) - 1
    edge_key = key[order[first]]
    return sides.reshape(-1, 3), np.stack([edge_key // n, edge_key % n], axis=1)


def edge_lengths(points, edges):
    """Lengths of ``edges`` ((e, 2) int) over ``points`` ((n, d) float): (e,) float."""
    d = points[edges[:, 1]] - points[edges[:, 0]]
    return np.sqrt(np.einsum("ij,ij->i", d, d))


def face_areas(points, faces):
    """Unsigned triangle areas: (m,) float, mm^2 (points (n, 2) or (n, 3))."""
    a = points[faces[:, 1]] - points[faces[:, 0]]
    b = points[faces[:, 2]] - points[faces[:, 0]]
    if points.shape[1] == 2:
        return 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    return 0.5 * np.linalg.norm(np.cross(a, b), axis=1)


def signed_areas_2d(points, faces):
    """Signed areas of triangles in the plane: (m,) float; > 0 counter-clockwise."""
    a = points[faces[:, 1], :2] - points[faces[:, 0], :2]
    b = points[faces[:, 2], :2] - points[faces[:, 0], :2]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def hat_gradients(xy, faces):
    """Gradients of the linear hat functions per face: ((m, 3, 2) 1/mm, signed areas (m,) mm^2).

    A per-vertex field ``f`` has gradient ``einsum("mi,mid->md", f[faces], gphi)`` in each face.
    """
    p = xy[faces]                                   # (m, 3, 2)
    area = signed_areas_2d(xy, faces)
    a2 = np.where(np.abs(area) > 1e-12, 2.0 * area, 1e-12)
    # grad(phi_i) = J(p_{i+2} - p_{i+1}) / 2A with J a quarter turn counter-clockwise.
    e = np.roll(p, -2, axis=1) - np.roll(p, -1, axis=1)
    gphi = np.stack([-e[..., 1], e[..., 0]], axis=-1) / a2[:, None, None]
    gphi[np.abs(area) <= 1e-12] = 0.0
    return gphi, area


def edge_index(edges, query):
    """Row of each ``query`` edge in sorted-pair ``edges``; -1 where absent.

    edges : (e, 2) int sorted pairs; query : (q, 2) int (any order). Returns (q,) int.
    """
    edges = np.asarray(edges, dtype=np.int64)
    q = np.sort(np.asarray(query, dtype=np.int64), axis=1)
    n = int(max(edges.max(initial=0), q.max(initial=0))) + 1
    keys = edges[:, 0] * n + edges[:, 1]
    order = np.argsort(keys)
    qk = q[:, 0] * n + q[:, 1]
    pos = np.searchsorted(keys[order], qk)
    pos = np.clip(pos, 0, len(keys) - 1)
    hit = keys[order][pos] == qk if len(keys) else np.zeros(len(qk), bool)
    out = np.full(len(qk), -1, dtype=np.int64)
    out[hit] = order[pos[hit]]
    return out


@dataclass
class HeightField:
    """A height field on a regular grid.

    Attributes
    ----------
    z : (rows, cols) float, mm
        Height above the lowest point; NaN outside the footprint.
        Row 0 is the top of the image (north); x = column * pixel_mm,
        y = (rows - 1 - row) * pixel_mm, so +y points north and faces seen
        from +z are counter-clockwise in (x, y).
    pixel_mm : float
        Grid spacing in mm.
    color : (rows, cols, 3) uint8 or None
        Optional surface colour per sample.
    source : str
        Where it came from (file name or shape name), for messages.
    up : dict or None
        For a mesh, which of its sides was taken as up and how
        (:func:`pipeline.input.meshread.orientation`); None for images and arrays.
    """

    z: np.ndarray
    pixel_mm: float
    color: np.ndarray = None
    source: str = ""
    up: dict = None

    @property
    def footprint(self):
        """(rows, cols) bool: where the field has data."""
        return np.isfinite(self.z)

    def xy(self, rows, cols):
        """Grid indices (float ok) to plane coordinates in mm: (..., 2)."""
        rows = np.asarray(rows, dtype=float)
        cols = np.asarray(cols, dtype=float)
        return np.stack([cols * self.pixel_mm,
                         (self.z.shape[0] - 1 - rows) * self.pixel_mm], axis=-1)

    def rc(self, xy):
        """Plane coordinates (..., 2) mm to fractional (row, col) indices."""
        xy = np.asarray(xy, dtype=float)
        return (self.z.shape[0] - 1 - xy[..., 1] / self.pixel_mm), xy[..., 0] / self.pixel_mm


def boundary_loops(faces):
    """Boundary loops of a triangle mesh, oriented like its faces.

    Parameters
    ----------
    faces : (m, 3) int, consistently oriented

    Returns
    -------
    loops : list of (k,) int
        Vertex indices of each closed loop (first vertex not repeated), longest
        first. Loops run along each face's own winding, so with counter-clockwise
        faces the outer boundary is counter-clockwise and holes clockwise.
    """
    faces = np.asarray(faces, dtype=np.int64)
    he = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    n = int(faces.max(initial=0)) + 1
    key = he[:, 0] * n + he[:, 1]
    twin = he[:, 1] * n + he[:, 0]
    if len(key) == 0:
        return []
    # A half-edge is on the boundary when no face runs its reverse (a binary
    # search in the sorted keys: several times faster than np.isin here).
    sorted_key = np.sort(key)
    pos = np.minimum(np.searchsorted(sorted_key, twin), len(key) - 1)
    border = he[sorted_key[pos] != twin]
    if len(border) == 0:
        return []
    order = np.argsort(border[:, 0], kind="stable")
    border = border[order]
    starts = np.searchsorted(border[:, 0], np.arange(n + 1))
    used = np.zeros(len(border), bool)
    loops = []
    # Walk boundary half-edges (O(boundary), not a hot path); a pinch vertex
    # with two outgoing boundary edges just yields two loops.
    for first in range(len(border)):
        if used[first]:
            continue
        loop = []
        e = first
        while not used[e]:
            used[e] = True
            loop.append(border[e, 0])
            v = border[e, 1]
            cand = np.arange(starts[v], starts[v + 1])
            cand = cand[~used[cand]]
            if len(cand) == 0:
                break
            e = cand[0]
        loops.append(np.asarray(loop, dtype=np.int64))
    loops.sort(key=len, reverse=True)
    return loops


def polyline_arc(points):
    """Arc length (mm) along the polyline ``points`` ((k, 2) mm) at each of its points,
    0 at the first: (k,)."""
    return np.r_[0.0, np.cumsum(np.hypot(*np.diff(points, axis=0).T))]


def polyline_length(points):
    """Length (mm) of the polyline ``points`` ((k, 2) mm; 0 for fewer than two)."""
    return float(np.hypot(*np.diff(points, axis=0).T).sum()) if len(points) > 1 else 0.0


def polyline_lengths(polylines):
    """Length (mm) of each of ``polylines`` (list of (k_i, 2) mm; 0 for fewer than two
    points), all at once: (p,). A call of :func:`polyline_length` per piece took 0.05 s
    on a stripe set's thousands."""
    if not len(polylines):
        return np.zeros(0)
    P = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 2) for p in polylines])
    k = np.array([len(p) for p in polylines])
    step = np.hypot(*np.diff(P, axis=0).T)
    # The step from each polyline's last point to the next one's first is not its own.
    ends = np.cumsum(k)[:-1][k[:-1] > 0] - 1
    step[ends[ends < len(step)]] = 0.0
    first = np.cumsum(k) - k
    out = np.add.reduceat(np.r_[step, 0.0], np.minimum(first, len(step)))
    return np.where(k > 1, out, 0.0)


def polygon_area(points):
    """Signed area of a closed polygon ((k, 2), first point not repeated); > 0 counter-clockwise."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
