"""Test meshes for the flattening and simulation solvers (not the real mesher).

Isolines (analytic rings, or contourpy loops of a height field) are resampled
at spacing <= ``l_u``; all samples plus a few fill points (apex, flat areas
between isolines) are triangulated by Delaunay in the plane; consecutive
samples of one isoline that end up joined by a mesh edge are printing edges,
every other edge is a bridge edge. This gives valid :class:`Mesh` objects
with isoline-aligned printing edges, which is all the solvers need.
"""

import numpy as np
from scipy.ndimage import map_coordinates, maximum_filter
from scipy.spatial import Delaunay, cKDTree

import contourpy

from pipeline.input import shapes
from pipeline.layout import curvature
from pipeline.layout.free import flatten_free
from pipeline.meshing.grid import build_grid_mesh
from pipeline.profiles.profile import load_profile
from pipeline.simulation.shell import simulate_shell, tensor_rest, thickness_for
from pipeline.geometry import Mesh, edge_index, signed_areas_2d, unique_edges


def resample_polyline(points, l_u, closed):
    """Points at equal arc-length spacing <= ``l_u`` along a polyline ((k, d) -> (j, d)).

    A closed polyline must not repeat its first point; the result does not either.
    """
    pts = np.asarray(points, dtype=float)
    ring = np.vstack([pts, pts[:1]]) if closed else pts
    seg = np.linalg.norm(np.diff(ring, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    count = max(int(np.ceil(total / l_u)), 3 if closed else 1)
    t = np.linspace(0.0, total, count + 1)
    if closed:
        t = t[:-1]
    return np.stack([np.interp(t, s, ring[:, k]) for k in range(ring.shape[1])], axis=1)


def mesh_from_loops(loops, closed, levels, extra=None, inside=None):
    """Delaunay mesh through isoline samples.

    Parameters
    ----------
    loops : list of (k_i, 3) float, mm
        Resampled isolines (closed loops without a repeated point, or open arcs).
    closed : list of bool
    levels : list of float, mm
        Height of each isoline.
    extra : (q, 3) float, optional
        Further vertices (apex, fill points); their edges are bridges.
    inside : callable (k, 2) -> (k,) bool, optional
        Footprint test for non-convex domains; triangles whose centroid or
        edge midpoints fall outside are dropped.
    """
    pts = [np.asarray(l, float) for l in loops]
    iso_id = np.concatenate([np.full(len(p), i) for i, p in enumerate(pts)])
    cand = []
    cand_iso = []
    start = 0
    for i, p in enumerate(pts):
        k = len(p)
        a = start + np.arange(k - (0 if closed[i] else 1))
        b = start + (np.arange(1, k + 1) % k if closed[i] else np.arange(1, k))
        cand.append(np.stack([a, b], axis=1))
        cand_iso.append(np.full(len(a), i))
        start += k
    verts = np.vstack(pts)
    vlevel = np.asarray(levels, float)[iso_id]
    if extra is not None and len(extra):
        extra = np.asarray(extra, float)
        verts = np.vstack([verts, extra])
        vlevel = np.concatenate([vlevel, extra[:, 2]])
    tri = Delaunay(verts[:, :2]).simplices.astype(np.int64)
    if inside is not None:
        probe = [verts[tri].mean(axis=1)[:, :2]]
        for i, j in ((0, 1), (1, 2), (2, 0)):
            probe.append(0.5 * (verts[tri[:, i], :2] + verts[tri[:, j], :2]))
        ok = np.logical_and.reduce([inside(q) for q in probe])
        tri = tri[ok]
    area = signed_areas_2d(verts, tri)
    tri = tri[np.abs(area) > 1e-9]
    flip = signed_areas_2d(verts, tri) < 0
    tri[flip] = tri[flip][:, ::-1]
    tri = _drop_non_manifold(tri)
    used = np.unique(tri)
    remap = np.full(len(verts), -1)
    remap[used] = np.arange(len(used))
    faces = remap[tri]
    edges = unique_edges(faces)
    cand = remap[np.vstack(cand)]
    cand_iso = np.concatenate(cand_iso)
    keep = (cand >= 0).all(axis=1)
    cand, cand_iso = cand[keep], cand_iso[keep]
    idx = edge_index(edges, cand)
    hit = idx >= 0
    is_print = np.zeros(len(edges), bool)
    is_print[idx[hit]] = True
    printing_iso = np.full(len(edges), -1)
    printing_iso[idx[hit]] = cand_iso[hit]
    return Mesh(vertices=verts[used], faces=faces, printing_edges=edges[is_print],
                bridge_edges=edges[~is_print], vertex_level=vlevel[used],
                printing_isoline=printing_iso[is_print],
                isoline_level=np.asarray(levels, float), isoline_closed=np.asarray(closed, bool),
                info={"isolines": len(loops)})


def _drop_non_manifold(tri):
    """Remove triangles at vertices where the boundary touches itself (bow ties)."""
    for _ in range(10):
        e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        e.sort(axis=1)
        uniq, inv, cnt = np.unique(e, axis=0, return_inverse=True, return_counts=True)
        bnd = uniq[cnt == 1]
        deg = np.bincount(bnd.ravel(), minlength=tri.max() + 1)
        bad = np.flatnonzero(deg > 2)
        if len(bad) == 0:
            return tri
        # Drop the boundary faces at the bad vertices; the rest stays a disk.
        on_bnd = (cnt[inv] == 1).reshape(3, -1).any(axis=0)
        touches = np.isin(tri, bad).any(axis=1)
        tri = tri[~(on_bnd & touches)]
    return tri


def spherical_cap(rho_mm=84.5, height_mm=25.0, ring_arc_mm=4.0, l_u=1.5, seed=0):
    """Polar mesh of a spherical cap with concentric isoline rings.

    Ring k lies at meridian arc length ``s_k = k * ring_arc_mm`` from the apex
    (radius ``rho sin(s/rho)``, a circle of constant height); the last ring is
    the rim. Returns (mesh, s_of_isoline) where ``s_of_isoline[i]`` is the arc
    length of isoline i (for the analytic check 1 - sin(phi)/phi).
    """
    rng = np.random.default_rng(seed)
    phi_max = np.arccos(1.0 - height_mm / rho_mm)
    s_max = rho_mm * phi_max
    n_rings = max(int(round(s_max / ring_arc_mm)), 2)
    s = np.linspace(0.0, s_max, n_rings + 1)[1:]
    loops, levels = [], []
    for sk in s:
        r = rho_mm * np.sin(sk / rho_mm)
        z = rho_mm * np.cos(sk / rho_mm) - (rho_mm - height_mm)
        count = max(int(np.ceil(2 * np.pi * r / l_u)), 6)
        t = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(count) / count
        loops.append(np.stack([r * np.cos(t), r * np.sin(t), np.full(count, z)], axis=1))
        levels.append(z)
    apex = np.array([[0.0, 0.0, height_mm]])
    mesh = mesh_from_loops(loops, [True] * len(loops), levels, extra=apex)
    return mesh, s


def isoline_mesh(hf, spacing_mm=2.0, l_u=1.5, level0_frac=0.08, fill_mm=None):
    """Mesh a :class:`HeightField` along its isolines (closed loops or open arcs).

    spacing_mm : height step between isolines; l_u : max printing edge length;
    fill_mm : if given, grid points farther than this from every isoline
    sample are added as vertices; summits (local maxima) always are.
    The footprint boundary is the isoline at ``level0_frac`` of the height.
    """
    z = hf.z[::-1]  # contourpy wants increasing y; row 0 of hf is north
    rows, cols = z.shape
    p = hf.pixel_mm
    x = np.arange(cols) * p
    y = np.arange(rows) * p
    zmax = float(np.nanmax(z))
    level0 = level0_frac * zmax
    gen = contourpy.contour_generator(x, y, z, line_type="Separate")
    loops, closed, levels = [], [], []
    for lev in np.arange(level0, zmax, spacing_mm):
        for line in gen.lines(lev):
            is_closed = np.allclose(line[0], line[-1])
            pts = line[:-1] if is_closed else line
            if len(pts) < 3:
                continue
            samples = resample_polyline(pts, l_u, is_closed)
            if is_closed and len(samples) < 4:
                continue
            loops.append(np.column_stack([samples, np.full(len(samples), lev)]))
            closed.append(bool(is_closed))
            levels.append(float(lev))

    def height(xy):
        rc = np.stack([xy[:, 1] / p, xy[:, 0] / p])  # rows of the flipped grid
        zz = np.nan_to_num(z, nan=-1.0)
        return map_coordinates(zz, rc, order=1, mode="constant", cval=-1.0)

    # Vertices off the isolines: summits (like the mesher's fan centres) and,
    # optionally, fill points in wide flat gaps. Bridge-only patches are stiff
    # in the flattening, so the default adds summits only.
    zz = np.nan_to_num(z, nan=-np.inf)
    peak = (zz == maximum_filter(zz, size=5)) & (zz > level0 + spacing_mm)
    pr, pc = np.nonzero(peak)
    extra = np.column_stack([pc * p, pr * p, z[pr, pc]])
    if fill_mm is not None:
        step = max(int(round(fill_mm / p / 2)), 1)
        gy, gx = np.mgrid[0:rows:step, 0:cols:step]
        cand = np.column_stack([gx.ravel() * p, gy.ravel() * p, z[gy, gx].ravel()])
        cand = cand[np.isfinite(cand[:, 2]) & (cand[:, 2] > level0 + 0.5 * spacing_mm)]
        iso_xy = np.vstack([l[:, :2] for l in loops])
        dist, _ = cKDTree(iso_xy).query(cand[:, :2])
        extra = np.vstack([extra, cand[dist > fill_mm]])
    # Chords of convex stretches sag slightly outside the boundary isoline.
    inside = lambda q: height(q) >= level0 - 0.1 * spacing_mm
    return mesh_from_loops(loops, closed, levels, extra=extra, inside=inside)


def reference_mesh(name, l_u=2.0, spacing_mm=2.5, pixel_mm=1.0):
    """Isoline mesh of one of :data:`pipeline.input.shapes.REFERENCE` at test resolution."""
    return isoline_mesh(shapes.REFERENCE[name](pixel_mm=pixel_mm), spacing_mm=spacing_mm, l_u=l_u)


def longest_diameter(mesh):
    """Largest distance between two boundary-ish vertices (mm), via the convex hull."""
    from scipy.spatial import ConvexHull
    xy = mesh.vertices[:, :2]
    h = xy[ConvexHull(xy).vertices]
    d = np.linalg.norm(h[:, None] - h[None], axis=2)
    return float(d.max())



def blended_caps(caps, tau_mm=3.0, pixel_mm=1.0, margin_mm=4.0):
    """Height field of elliptic caps blended by a soft maximum.

    caps : list of (cx, cy, a, b, angle_rad, height) in mm. Each cap is
    ``h (sqrt(2 - q) - 1) / (sqrt(2) - 1)`` with q the elliptic radius
    squared: positive Gaussian curvature up to its rim, which meets the
    ground at a finite slope. The soft maximum ``tau log sum exp(z_i / tau)``
    joins caps through smooth saddles. Caps keep their rims curved, so a
    flattened layout holds its shape (a rim that is nearly developable would
    unroll under the bending toward flat and dominate the simulated error).
    """
    from pipeline.geometry import HeightField
    pts = np.array([[cx - max(a, b), cy - max(a, b), cx + max(a, b), cy + max(a, b)]
                    for cx, cy, a, b, _, _ in caps])
    lo = pts[:, :2].min(axis=0) - margin_mm
    hi = pts[:, 2:].max(axis=0) + margin_mm
    nx = int(np.ceil((hi[0] - lo[0]) / pixel_mm)) + 1
    ny = int(np.ceil((hi[1] - lo[1]) / pixel_mm)) + 1
    x, y = np.meshgrid(lo[0] + np.arange(nx) * pixel_mm, hi[1] - np.arange(ny) * pixel_mm)
    acc = np.zeros_like(x)
    for cx, cy, a, b, ang, h in caps:
        u = (x - cx) * np.cos(ang) + (y - cy) * np.sin(ang)
        v = -(x - cx) * np.sin(ang) + (y - cy) * np.cos(ang)
        q = (u / a) ** 2 + (v / b) ** 2
        z = h * (np.sqrt(np.maximum(2.0 - q, 0.0)) - 1.0) / (np.sqrt(2.0) - 1.0)
        acc += np.where(q <= 1.0, np.exp(z / tau_mm), 0.0)
    z = np.where(acc > 0, tau_mm * np.log(np.maximum(acc, 1e-300)), np.nan)
    return HeightField(z - np.nanmin(z), pixel_mm, source="blended_caps")


def two_peaks(height_mm=28.0, pixel_mm=1.0):
    """Two summits (28 and 22 mm) joined by a saddle, ~150 mm long."""
    return blended_caps([(-35.0, 0.0, 45.0, 40.0, 0.0, height_mm),
                         (35.0, 0.0, 42.0, 38.0, 0.0, 0.8 * height_mm)], pixel_mm=pixel_mm)



def starfish_like(diameter_mm=170.0, height_mm=30.0, arms=5, neck=0.6, pixel_mm=1.0):
    """One summit, five lobes: a cap over a star-shaped outline.

    The outline is ``r_b(phi) = R (neck + (1 - neck) |cos(arms phi / 2)|^2)``
    (non-convex for neck < ~0.8) and the height a spherical-cap profile of
    ``rho = r / r_b(phi)``. Blunter necks than :func:`pipeline.input.shapes.starfish`
    keep the total Gaussian curvature positive.
    """
    from pipeline.geometry import HeightField
    R = diameter_mm / 2.0
    n = int(round((diameter_mm + 8 * pixel_mm) / pixel_mm)) + 1
    c = (np.arange(n) - (n - 1) / 2.0) * pixel_mm
    x, y = np.meshgrid(c, -c)
    r, phi = np.hypot(x, y), np.arctan2(y, x)
    rb = R * (neck + (1.0 - neck) * np.abs(np.cos(arms * phi / 2.0)) ** 2)
    q = (r / rb) ** 2
    z = height_mm * (np.sqrt(np.maximum(2.0 - q, 0.0)) - 1.0) / (np.sqrt(2.0) - 1.0)
    return HeightField(np.where(q <= 1.0, z, np.nan), pixel_mm, source="starfish_like")


def flat_sheet(nx=13, ny=7, size=(24.0, 12.0), jitter=0.0, seed=0):
    """A flat, consistently oriented triangulation of a rectangle: (V (n, 3), faces)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, size[0], nx), np.linspace(0, size[1], ny))
    pts = np.c_[x.ravel(), y.ravel()]
    inner = (pts[:, 0] > 0) & (pts[:, 0] < size[0]) & (pts[:, 1] > 0) & (pts[:, 1] < size[1])
    pts[inner] += rng.uniform(-jitter, jitter, size=(inner.sum(), 2))
    faces = Delaunay(pts).simplices
    P = pts[faces]
    cross = ((P[:, 1, 0] - P[:, 0, 0]) * (P[:, 2, 1] - P[:, 0, 1])
             - (P[:, 1, 1] - P[:, 0, 1]) * (P[:, 2, 0] - P[:, 0, 0]))
    faces[cross < 0] = faces[cross < 0][:, [0, 2, 1]]
    return np.c_[pts, np.zeros(len(pts))], faces


def roll_curvature(P):
    """Curvature (1/mm) of a strip rolled about an axis along its width: one circle
    fitted to all its points ((n, 3) mm) in the plane across that axis."""
    axis = np.linalg.svd(P - P.mean(axis=0))[2]
    width = axis[np.argmax(np.abs(axis @ np.array([0.0, 1.0, 0.0])))]
    u = np.cross(width, [0.0, 0.0, 1.0] if abs(width[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(width, u)
    xz = np.c_[P @ u, P @ w]
    A = np.c_[2 * xz, np.ones(len(xz))]
    b = (xz ** 2).sum(axis=1)
    cx, cz, c = np.linalg.lstsq(A, b, rcond=None)[0]
    return 1.0 / np.sqrt(c + cx ** 2 + cz ** 2)


# The free method's sheet, for the simulation's tests: the shipped profile's materials.
SHEET_PROFILE = load_profile("generic-0.5mm")
LIMITS = SHEET_PROFILE.shrink_limits


def sheet_thickness(sigma):
    """Printed thickness (mm) of triangles of shrink ``sigma`` with the shipped profile."""
    return thickness_for(sigma, SHEET_PROFILE.shrink_curve, SHEET_PROFILE.layers,
                         SHEET_PROFILE.thickness_mm.min, SHEET_PROFILE.thickness_mm.max)


def free_sheet(hf, spacing_mm, programmed=True, turn_max_deg=None):
    """The free method's sheet on a ``spacing_mm`` grid as the plan simulates it:
    started flat, the curvature programmed through the layers (or not), its layer groups
    turned apart up to ``turn_max_deg`` (default: the profile's). SimResult."""
    mesh = build_grid_mesh(hf, spacing_mm)
    flat = flatten_free(mesh, LIMITS.s_min, LIMITS.s_max, iterations=200)
    sigma = np.clip(flat.sigma, LIMITS.s_min, LIMITS.s_max)
    thick = sheet_thickness(sigma)
    shrink = sigma[:, None, None] * np.einsum("mi,mj->mij", flat.direction, flat.direction)
    theta = None
    if programmed:
        K = curvature.target_tensor(hf, mesh, flat, sigma)
        sigma = curvature.room_for(K, flat.direction, sigma, thick, LIMITS.s_min, LIMITS.s_max,
                                   added_max=SHEET_PROFILE.curvature.max_added_shrink)
        thick = sheet_thickness(sigma)
        prog = curvature.program(K, mesh.faces,
                                 flat.xy, flat.direction, sigma, thick, LIMITS.s_min,
                                 LIMITS.s_max, turn_max_deg=(
                                     SHEET_PROFILE.curvature.turn_max_deg
                                     if turn_max_deg is None else turn_max_deg))
        A, B = prog.group_tensors(flat.direction, sigma)
        theta, shrink = prog.theta_rest, (A + B) / 2
    return simulate_shell(mesh.vertices, mesh.faces, flat.xy,
                          tensor_rest(flat.xy, mesh.faces, shrink), thick,
                          theta_rest=theta, pop=0.0)


# Mesh-refinement studies run on 60 mm models: meshed every 0.9 mm they have the plan's
# relative resolution of a 100 mm model every 1.5 mm, coarser than the shipped
# profiles, so a pass is on the safe side.
REFINE_SIZE_MM = 60.0
REFINE_SPACING_MM = 0.9
REFINE_SHAPES = {
    "dome": lambda: shapes.dome(REFINE_SIZE_MM, REFINE_SIZE_MM * 25 / 120, pixel_mm=0.2),
    "monkey_saddle": lambda: shapes.monkey_saddle(REFINE_SIZE_MM, REFINE_SIZE_MM * 22 / 136,
                                                  pixel_mm=0.2),
    "starfish": lambda: shapes.starfish(REFINE_SIZE_MM, REFINE_SIZE_MM * 33.4 / 175,
                                        pixel_mm=0.2),
}


def refines_within(sheet, shape, tolerance=0.10):
    """Mean displacements (coarse, fine) of ``sheet(hf, spacing_mm)`` on a refinement
    shape at the study's spacing and half of it; asserts they agree within ``tolerance``."""
    hf = REFINE_SHAPES[shape]()
    coarse, fine = (sheet(hf, s).mean_displacement_mm
                    for s in (REFINE_SPACING_MM, REFINE_SPACING_MM / 2))
    assert fine > 0
    assert abs(coarse - fine) < tolerance * fine, (coarse, fine)
    return coarse, fine

