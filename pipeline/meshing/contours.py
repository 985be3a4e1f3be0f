"""Isolines of a height field, clipped to its footprint (paper 6.1, first half).

The mesher works on a *guide field* ``g = z + flat_slope * d``, where ``d`` is
a smoothed distance to the footprint boundary. Where the terrain is sloped the
small ramp changes little; where it is flat (a sea-level base, a plateau) it
turns the isolines into offsets of the outline, so flat areas still get
printing directions (parallel to the edge) and gradient lines (toward it).
Outside the footprint the field is extended downhill so low isolines close
instead of being cut at the last pixel; isolines are then clipped to the
footprint outline, which makes the pieces that cross it open arcs ending
exactly on the outline.
"""

from dataclasses import dataclass

import contourpy
import numpy as np
import shapely
from scipy import ndimage

from pipeline.errors import MeshingError
from pipeline.geometry import polygon_area

PAD_PX = 4


@dataclass
class Piece:
    """One isoline piece, or the footprint outline.

    points : (k, 2) float, mm; for closed pieces the first point is not repeated.
    closed : bool
    level : float, guide-field value (mm); for a sloped outline, NaN.
    kind : "iso" or "outline"
    cum : (k,) or (k+1,) float, arc length at each point (closed: includes the
        closing segment as the last entry).
    """

    points: np.ndarray
    closed: bool
    level: float
    kind: str
    cum: np.ndarray = None

    def __post_init__(self):
        p = self.points
        if self.closed:
            p = np.vstack([p, p[:1]])
        self._path = p
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        self.cum = np.concatenate([[0.0], np.cumsum(seg)])

    @property
    def length(self):
        return float(self.cum[-1])

    def at(self, t):
        """Points at arc-length parameters ``t`` ((q,) float): (q, 2)."""
        p = self._path
        t = np.asarray(t, dtype=float)
        if self.closed:
            t = np.mod(t, self.length)
        return np.stack([np.interp(t, self.cum, p[:, 0]), np.interp(t, self.cum, p[:, 1])], axis=-1)


class GuideField:
    """The guide field on a padded grid, with bilinear sampling of value and gradient.

    Parameters
    ----------
    hf : HeightField (validated; NaN outside the footprint)
    flat_slope : float
        Ramp added per mm of distance from the boundary (dimensionless).
    smooth_mm : float
        Smoothing of the distance ramp (keeps its medial-axis creases soft).
    """

    def __init__(self, hf, flat_slope=0.05, smooth_mm=3.0):
        self.pixel_mm = p = float(hf.pixel_mm)
        inside = np.pad(np.isfinite(hf.z), PAD_PX, constant_values=False)
        z = np.pad(np.where(np.isfinite(hf.z), hf.z, 0.0), PAD_PX)
        d_in = ndimage.distance_transform_edt(inside) * p
        d_in = ndimage.gaussian_filter(d_in, smooth_mm / p) if smooth_mm > 0 else d_in
        d_in = np.where(inside, d_in, 0.0)
        d_out, idx = ndimage.distance_transform_edt(~inside, return_indices=True)
        near = (idx[0], idx[1])
        g_in = z + flat_slope * d_in
        # Outside: continue downhill from the nearest inside value so isolines close.
        g = np.where(inside, g_in, g_in[near] - d_out * p)
        zx = np.where(inside, z, z[near])
        self.inside = inside
        self.g = g
        self.z = zx
        self.rows = g.shape[0]
        # Gradient in mm/mm with +y = north = decreasing row.
        grow, gcol = np.gradient(g, p)
        self.gx, self.gy = gcol, -grow
        # Signed distance to the footprint edge, in mm (> 0 inside), for the outline.
        # (lightly smoothed so the outline of a pixelated disc is round, not stepped).
        sdf = np.where(inside, ndimage.distance_transform_edt(inside) - 0.5,
                       -(ndimage.distance_transform_edt(~inside) - 0.5)) * p
        self.sdf = ndimage.gaussian_filter(sdf, 1.0)
        self.inside_values = hf.z[np.isfinite(hf.z)]

    # Grid coordinates: x = (col - PAD) * p, y = (rows - 1 - row - PAD) * p, matching HeightField.xy.
    def _rc(self, xy):
        p = self.pixel_mm
        xy = np.asarray(xy, dtype=float)
        rc = np.empty((2,) + xy.shape[:-1])
        np.subtract(self.rows - 1 - PAD_PX, xy[..., 1] / p, out=rc[0])
        np.add(xy[..., 0] / p, PAD_PX, out=rc[1])
        return rc

    @staticmethod
    def _at(grid, rc, order=1):
        # The output array given: without it map_coordinates spends most of a call of a
        # few points looking up the name of the input's dtype to allocate one.
        out = np.empty(rc.shape[1:], dtype=grid.dtype)
        ndimage.map_coordinates(grid, rc.reshape(2, -1), output=out.reshape(-1),
                                order=order, mode="nearest")
        return out

    def sample(self, grid, xy, order=1):
        """Sample a padded grid (e.g. ``self.g``) at points ``xy`` ((..., 2) mm)."""
        return self._at(grid, self._rc(xy), order)

    def value(self, xy):
        return self.sample(self.g, xy)

    def height(self, xy):
        """True surface height z (mm) at ``xy``."""
        return self.sample(self.z, xy)

    def gradient(self, xy):
        rc = self._rc(xy)
        out = np.empty(rc.shape[1:] + (2,))
        out[..., 0] = self._at(self.gx, rc)
        out[..., 1] = self._at(self.gy, rc)
        return out

    def axes(self):
        """1-D x and (increasing) y coordinates of the padded grid, and the flip for y."""
        p = self.pixel_mm
        cols = self.g.shape[1]
        x = (np.arange(cols) - PAD_PX) * p
        y = (np.arange(self.rows) - PAD_PX) * p  # row index flipped: row r -> y[rows-1-r]
        return x, y

    def contour(self, grid, level):
        """Lines of ``grid`` at ``level``, as a list of (k, 2) arrays in mm."""
        x, y = self.axes()
        gen = contourpy.contour_generator(x=x, y=y, z=grid[::-1], line_type="Separate")
        return gen.lines(level)


def points_at(pieces, pids, ts):
    """Points on several pieces: ``pieces[pids[i]].at(ts[i])`` for all i, (q, 2)."""
    pids = np.asarray(pids, dtype=np.int64)
    ts = np.asarray(ts, dtype=float)
    out = np.zeros((len(pids), 2))
    for pid in np.unique(pids):
        sel = pids == pid
        out[sel] = pieces[pid].at(ts[sel])
    return out


def footprint_outline(field, spacing_mm):
    """The footprint's outline as a closed, counter-clockwise polyline.

    Returns ``(points (k, 2) mm, polygon)`` resampled at ``spacing_mm``.
    """
    lines = field.contour(field.sdf, 0.0)
    closed = [ln for ln in lines if len(ln) > 3 and np.allclose(ln[0], ln[-1])]
    if not closed:
        raise MeshingError("the footprint has no closed outline", code="mesh.no_outline",
                           fix="check that the height field has a footprint of data")
    ring = max(closed, key=lambda ln: abs(polygon_area(ln)))
    ring = ring[:-1]
    if polygon_area(ring) < 0:
        ring = ring[::-1]
    piece = Piece(ring, True, np.nan, "outline")
    n = max(int(np.ceil(piece.length / spacing_mm)), 8)
    pts = piece.at(np.linspace(0, piece.length, n, endpoint=False))
    return pts, shapely.Polygon(pts)


def isoline_pieces(field, polygon, levels, min_length_mm):
    """Isoline pieces of the guide field at ``levels``, clipped to ``polygon``.

    Returns a list of :class:`Piece` (kind "iso"), oriented with higher ground
    on the left. Pieces shorter than ``min_length_mm`` are dropped.
    """
    shapely.prepare(polygon)
    boundary = polygon.exterior
    pieces = []
    for level in levels:
        lines = [ln for ln in field.contour(field.g, level) if len(ln) >= 2]
        if not lines:
            continue
        geoms = np.array([shapely.LineString(ln) for ln in lines], dtype=object)
        inside = shapely.contains(polygon, geoms)
        for ln, geom, whole in zip(lines, geoms, inside):
            if whole:
                parts = [np.asarray(ln)]
            else:
                clipped = shapely.line_merge(shapely.intersection(geom, polygon))
                parts = [np.asarray(g.coords) for g in shapely.get_parts(clipped)
                         if g.geom_type == "LineString" and len(g.coords) >= 2]
            for pts in parts:
                closed = len(pts) > 3 and np.allclose(pts[0], pts[-1]) and \
                    shapely.distance(boundary, shapely.Point(pts[0])) > 1e-6
                if closed:
                    pts = pts[:-1]
                pts = _dedupe(pts)
                if len(pts) < 2:
                    continue
                piece = Piece(pts, closed, float(level), "iso")
                if piece.length < min_length_mm:
                    continue
                pieces.append(_orient_uphill_left(field, piece))
    return pieces


def _dedupe(pts, eps=1e-9):
    keep = np.ones(len(pts), bool)
    keep[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1) > eps
    return pts[keep]


def _orient_uphill_left(field, piece):
    """Reverse ``piece`` if the guide field rises to its right."""
    p = piece.points if not piece.closed else np.vstack([piece.points, piece.points[:1]])
    mid = 0.5 * (p[1:] + p[:-1])
    tan = np.diff(p, axis=0)
    left = np.stack([-tan[:, 1], tan[:, 0]], axis=1)
    norm = np.linalg.norm(left, axis=1, keepdims=True)
    left = left / np.maximum(norm, 1e-12)
    grad = field.gradient(mid)
    w = norm[:, 0]
    if np.sum(w * np.einsum("ij,ij->i", grad, left)) < 0:
        return Piece(piece.points[::-1].copy(), piece.closed, piece.level, piece.kind)
    return piece
