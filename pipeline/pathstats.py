"""Figures of a tool-path plan: the report's ``toolpath`` section.

Spacing (from points on each path to the nearest other path), coverage and
overlap of the flat footprint (within half a path width of one path, or of
two), sharp turns inside traces, and how far the paths turn away from the
isolines they should follow (the shrink acts along the path).
"""

import numpy as np
from scipy.spatial import cKDTree

from pipeline.geometry import hat_gradients


def path_metrics(traces, tsig, raw, xy, faces, level, u, poly, pw):
    """The report's ``toolpath`` section.

    Parameters
    ----------
    traces : list of (k, 2) float, mm; tsig : list of (k - 1,) float
    raw : list of ((k, 2) float, closed bool), the loops and arcs before chaining
    xy : (n, 2) float, mm, flat layout; faces : (m, 3) int
    level, u : (n,) float, isoline value and path index per vertex
    poly : shapely polygon, the flat outline; pw : float, path width mm
    """
    import shapely

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
    samples, label = [], []
    for c, (p, _) in enumerate(raw):
        q = _densify(p, pw / 4)
        samples.append(q)
        label.append(np.full(len(q), c))
    samples = np.concatenate(samples)
    label = np.concatenate(label)
    tree = cKDTree(samples)
    probe = np.arange(0, len(samples), 3)
    d, i = tree.query(samples[probe], k=14, distance_upper_bound=3 * pw)
    i = np.minimum(i, len(label) - 1)
    other = (label[i] != label[probe][:, None]) & np.isfinite(d)
    has = other.any(axis=1)
    spacing = d[has, np.argmax(other[has], axis=1)]
    # Coverage and overlap on a grid over the flat footprint (``poly``, its outline).
    res = pw / 2.5
    x0, y0 = xy.min(axis=0)
    x1, y1 = xy.max(axis=0)
    X, Y = np.meshgrid(np.arange(x0, x1, res) + res / 2, np.arange(y0, y1, res) + res / 2)
    inside = shapely.contains_xy(poly, X.ravel(), Y.ravel())
    grid = np.column_stack([X.ravel()[inside], Y.ravel()[inside]])
    # Only neighbours within half a path width decide coverage and overlap, and
    # the tighter bound prunes most of the tree walk (nextafter: a point exactly
    # half a width away still counts, as the tests below use <=).
    d, i = tree.query(grid, k=6, distance_upper_bound=np.nextafter(pw / 2, np.inf))
    covered = d[:, 0] <= pw / 2
    first = label[np.minimum(i[:, 0], len(label) - 1)]
    lab = label[np.minimum(i, len(label) - 1)]
    twice = ((lab != first[:, None]) & (d < 0.999 * pw / 2)).any(axis=1) & covered
    pct = np.percentile(spacing, [5, 50, 95]) if len(spacing) else [np.nan] * 3
    return {"traces": len(traces), "segments": int(seg_count), "length_mm": length,
            "travel_moves": max(len(traces) - 1, 0), "sharp_turns": sharp,
            "spacing_mm": {"target": pw, "p05": float(pct[0]), "p50": float(pct[1]),
                           "p95": float(pct[2])},
            "coverage": float(covered.mean()) if len(grid) else 0.0,
            "overlap": float(twice.mean()) if len(grid) else 0.0,
            "loops_and_arcs": len(raw),
            "isoline_angle_deg": dict(zip(("p50", "p95"), _weighted_percentiles(
                *isoline_angles(xy, faces, level, u), [50, 95])))}


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


def _densify(points, step):
    """Points along a polyline at most ``step`` apart: (q, 2)."""
    d = np.diff(points, axis=0)
    n = np.maximum(np.ceil(np.hypot(d[:, 0], d[:, 1]) / step).astype(int), 1)
    seg = np.repeat(np.arange(len(d)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / n[seg]
    return np.vstack([points[seg] + d[seg] * t[:, None], points[-1:]])
