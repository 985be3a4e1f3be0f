"""Curvature programmed through the layers: a bilayer per triangle.

A layout fixes each triangle's mean shrink (its metric). Printing the lower layers
of the same paths with a larger shrink than the upper ones (thinner lower layers)
adds a natural curvature along the path direction ``d``, as in a bimetal strip:
``kappa = c * (sigma_bottom - sigma_top) / h`` (Timoshenko's bilayer gives c = 3/2
for two equal layers of one material; the profile's calibration measures it).
Positive kappa curls the sheet away from its lower side: a dome rising off the bed.

The design here picks, per triangle, the target's normal curvature along ``d`` (from
the smoothed height field's second derivatives, not from the mesh's dihedral angles,
which near a steep rim or in a thin triangle measure the mesher's rounding), within
what the shrink range allows around the triangle's mean shrink:
``|sigma_bottom - sigma_top| <= 2 * min(sigma - s_min, s_max - sigma)``.
Bending then pulls toward the target instead of toward flat, and the sign of the
program decides which way each region rises in the bath.

The target's twist (its curvature ``d^T K e`` across the paths) is programmed by
turning the two layer groups apart, the lower one by ``a`` and the upper one by ``b``
off ``d`` (:func:`crossing`): their mean keeps the layout's metric to first order, their
difference is a twist, as in a laminate of two plies a few degrees apart. The rest
(curvature across ``d``) cannot be programmed without changing the metric, so where the
layout leaves the direction free (``sigma`` near 0: the starfish's arms, most of a
dome's rim) ``d`` is turned toward the direction the target bends most
(:func:`bend_free_directions`).
"""

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import (binary_erosion, distance_transform_edt, gaussian_filter,
                           map_coordinates)

from pipeline.geometry import hat_gradients, quarter_turn
from pipeline.mechanics.constraints import topology

# Timoshenko's bilayer, equal thickness and modulus: kappa = 1.5 * delta_strain / h.
BILAYER_C = 1.5
# The program reads the target smoothed this much: curvature finer than a few path
# widths pulls each small ridge one way only and leaves the real tiles further off
# (measured with 1 mm: coast tile 9.6 % against 5.3 %).
PROGRAM_SMOOTH_MM = 5.0


@dataclass
class CurvatureProgram:
    """Per-triangle layer program and the rest dihedral angles it gives.

    kappa : (m,) 1/mm, curvature along ``d`` (positive: rising off the bed)
    delta_sigma : (m,) sigma_bottom - sigma_top
    limited : (m,) bool, the shrink range cut the wanted curvature
    theta_rest : (h,) rad, rest dihedral angle of each hinge (``topology(faces).hinges``)
    turn_bottom, turn_top : (m,) rad, how far the lower and the upper layer group turn
    off ``d`` (counter-clockwise; both 0 without twist)
    twist : the comparison that chose whether the groups turn apart, or None
    sigma : (m,) the mean shrink the program was made for (printed as such)
    added : the shrink :func:`room_for` added to the layout's, {area_fraction, max}, or None
    laminate : :class:`pipeline.layout.laminate.Laminate` where two layers print
    across ``d``, or None
    across : the comparison that chose whether they do, or None
    layout : the :class:`pipeline.layout.free.FreeLayout` the program prints on where it
    is not the plan's first (the layers across are printed on a layout solved again for
    their shrink, :mod:`pipeline.layout.compensate`), or None
    """

    kappa: np.ndarray
    delta_sigma: np.ndarray
    limited: np.ndarray
    theta_rest: np.ndarray
    turn_bottom: np.ndarray = None
    turn_top: np.ndarray = None
    twist: dict = None
    sigma: np.ndarray = None
    added: dict = None
    laminate: object = None
    across: dict = None
    layout: object = None

    @property
    def crossed(self):
        """The two layer groups print along different directions somewhere."""
        return self.turn_bottom is not None and bool(
            np.any(self.turn_bottom != 0) or np.any(self.turn_top != 0))

    def group_directions(self, direction):
        """Print directions of the lower and the upper layer group: two (m, 2) unit."""
        if self.turn_bottom is None:
            return np.asarray(direction, dtype=float), np.asarray(direction, dtype=float)
        return turned(direction, self.turn_bottom), turned(direction, self.turn_top)

    def group_tensors(self, direction, sigma):
        """Shrink tensors (m, 2, 2) of the lower and the upper layer group in the layout:
        ``s_b d_b d_b^T`` and ``s_t d_t d_t^T``. Their mean is the sheet's metric, their
        difference times ``c / h`` its natural curvature."""
        d_b, d_t = self.group_directions(direction)
        s_b = np.asarray(sigma, dtype=float) + self.delta_sigma / 2
        s_t = np.asarray(sigma, dtype=float) - self.delta_sigma / 2
        return (s_b[:, None, None] * np.einsum("mi,mj->mij", d_b, d_b),
                s_t[:, None, None] * np.einsum("mi,mj->mij", d_t, d_t))

    def report(self):
        """The report's ``curvature`` section."""
        out = {"limited_fraction": float(self.limited.mean()) if len(self.limited) else 0.0,
               "delta_sigma": {"p05": float(np.percentile(self.delta_sigma, 5)),
                               "p95": float(np.percentile(self.delta_sigma, 95)),
                               "max_abs": float(np.abs(self.delta_sigma).max())}}
        if self.turn_bottom is not None:
            out["crossing_deg"] = self.crossing_deg()
        if self.twist is not None:
            out["twist"] = dict(self.twist)
        if self.added is not None:
            out["added_shrink"] = dict(self.added)
        if self.across is not None:
            out["across"] = dict(self.across, **(self.laminate.report() if self.laminate else {}))
        return out

    def crossing_deg(self):
        """How far apart the two layer groups print: {p50, p95, max} degrees."""
        apart = np.degrees(np.abs(self.turn_bottom - self.turn_top))
        return {"p50": float(np.percentile(apart, 50)), "p95": float(np.percentile(apart, 95)),
                "max": float(apart.max())}


def isoline_directions(xy, faces, vertex_level, level=(1.0, 0.0)):
    """Print direction of each triangle of an isoline layout: along the isolines,
    i.e. across the gradient of the isoline height in the layout: (m, 2) unit, and
    ``level`` in a triangle without a gradient."""
    gphi, _ = hat_gradients(np.asarray(xy, dtype=float), faces)
    grad = np.einsum("mi,mid->md", np.asarray(vertex_level, dtype=float)[faces], gphi)
    d = np.stack([-grad[:, 1], grad[:, 0]], axis=1)
    norm = np.linalg.norm(d, axis=1)
    d[norm < 1e-12] = level
    norm[norm < 1e-12] = 1.0
    return d / norm[:, None]


def surface_derivatives(hf, smooth_mm=1.0):
    """First and second derivatives of a height field, for sampling anywhere.

    Returns a function ``(points (k, 2) mm) -> (fx, fy, fxx, fxy, fyy)``, each (k,).
    Each derivative is smoothed over the footprint only (a Gaussian of ``smooth_mm``
    weighted by the pixels whose differences see no pixel outside it), so a rim's
    derivatives are the surface's. The field continued past the rim by its nearest
    sample, then smoothed, met the rim with a kink: on the starfish, a cap whose arms
    end at a slope of 0.9, the Hessian within a smoothing of the edge curled up where
    the cap curls down, and the arm tips were programmed to rise.
    """
    z = np.asarray(hf.z, dtype=float)
    inside = np.isfinite(z)
    idx = distance_transform_edt(~inside, return_distances=False, return_indices=True)
    z = z[tuple(idx)]
    px = hf.pixel_mm
    # Rows run south: d/dy = -d/drow.
    z_r, z_c = np.gradient(z, px)
    fx, fy = z_c, -z_r
    fields = (fx, fy, np.gradient(fx, px, axis=1), -np.gradient(fx, px, axis=0),
              -np.gradient(fy, px, axis=0))
    sigma = smooth_mm / px
    if sigma > 0:
        # Second differences reach two pixels: nearer the rim they see the continuation.
        seen = binary_erosion(inside, iterations=2, border_value=1)
        if not seen.any():
            seen = inside
        weight = np.maximum(gaussian_filter(seen.astype(float), sigma, mode="nearest"), 1e-12)
        fields = tuple(gaussian_filter(np.where(seen, f, 0.0), sigma, mode="nearest") / weight
                       for f in fields)

    def at(points):
        r, c = hf.rc(np.asarray(points, dtype=float))
        return tuple(map_coordinates(f, [r, c], order=1, mode="nearest") for f in fields)
    return at


def normal_curvature(derivs, points, direction):
    """Normal curvature of the surface along a direction, positive for a dome.

    derivs : from :func:`surface_derivatives`; points : (k, 2) mm; direction :
    (k, 2), the direction's (x, y) components (its z follows the surface).
    Returns (k,) 1/mm, ``-II(t, t) / I(t, t)`` with the upward normal.
    """
    fx, fy, fxx, fxy, fyy = derivs(points)
    a, b = np.asarray(direction, dtype=float).T
    first = a * a * (1 + fx * fx) + 2 * a * b * fx * fy + b * b * (1 + fy * fy)
    second = (a * a * fxx + 2 * a * b * fxy + b * b * fyy) / np.sqrt(1 + fx * fx + fy * fy)
    return -second / np.maximum(first, 1e-300)


def isoline_tangents(derivs, points):
    """Horizontal unit tangents of the isolines at ``points``: (k, 2)."""
    fx, fy = derivs(points)[:2]
    t = np.stack([-fy, fx], axis=1)
    norm = np.linalg.norm(t, axis=1)
    t[norm < 1e-12] = (1.0, 0.0)
    return t / np.maximum(norm, 1e-12)[:, None]


def program(K_target, faces, xy, direction, sigma, thickness_mm, s_min, s_max,
            c=BILAYER_C, turn_max_deg=0.0):
    """The layer program that brings the sheet's rest curvature closest to the target's.

    K_target : (m, 2, 2) 1/mm, the target's curvature in the layout frame after the
    shrink (:func:`target_tensor`; positive for a dome); faces : (m, 3); xy : (n, 2) mm,
    the layout; direction : (m, 2) unit print direction in the layout; sigma : (m,)
    mean shrink; thickness_mm : (m,). With ``turn_max_deg`` > 0 the two layer groups
    also turn apart (at most that far off ``d``) to program the target's twist.
    Returns :class:`CurvatureProgram`.
    """
    faces = np.asarray(faces, dtype=np.int64)
    top = topology(faces, len(xy))
    sigma = np.asarray(sigma, dtype=float)
    d = np.asarray(direction, dtype=float)
    e = quarter_turn(d)
    K = np.asarray(K_target, dtype=float)
    h = np.asarray(thickness_mm, dtype=float)
    room = 2.0 * np.clip(np.minimum(sigma - s_min, s_max - sigma), 0.0, None)
    k_max = c * room / h
    kappa = np.einsum("mi,mij,mj->m", d, K, d)
    limited = np.abs(kappa) > k_max
    kappa = np.clip(kappa, -k_max, k_max)
    delta = kappa * h / c
    turn_b, turn_t = crossing(np.einsum("mi,mij,mj->m", d, K, e) * h / c,
                              sigma + delta / 2, sigma - delta / 2, turn_max_deg)
    prog = CurvatureProgram(kappa=kappa, delta_sigma=delta, limited=limited,
                            theta_rest=None, turn_bottom=turn_b, turn_top=turn_t, sigma=sigma)
    A, B = prog.group_tensors(d, sigma)
    prog.theta_rest = rest_angles(xy, faces, (A + B) / 2, c * (A - B) / h[:, None, None], top)
    return prog


def room_for(K_target, direction, sigma, thickness_mm, s_min, s_max, c=BILAYER_C,
             added_max=0.0):
    """The mean shrink to print so that the bilayer has room for the target's curvature
    along ``d``: (m,). A thickness difference needs shrink on both sides of the mean, so
    where the layout asks less than ``s_min + |delta| / 2`` (the direction free, ``sigma``
    near 0: a starfish's arms) the mean is raised to it, by at most ``added_max``. The
    metric gives that much along ``d`` where the curvature is worth more."""
    d = np.asarray(direction, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    want = np.abs(np.einsum("mi,mij,mj->m", d, np.asarray(K_target, dtype=float), d))
    need = s_min + 0.5 * want * np.asarray(thickness_mm, dtype=float) / c
    return np.clip(np.maximum(sigma, np.minimum(need, sigma + added_max)), None, s_max)


def crossing(twist, s_bottom, s_top, turn_max_deg):
    """How far each layer group turns off ``d`` (rad, toward ``e`` = ``d`` turned a
    quarter left) so that the two differ by ``twist`` (dimensionless, the target's
    ``h/c * d^T K e``) while their mean keeps no shear: ``s_b sin 2a = twist =
    -s_t sin 2b``. Where a group would have to turn further than ``turn_max_deg`` the
    twist is cut to what that turn gives. Returns (turn_bottom (m,), turn_top (m,))."""
    twist = np.asarray(twist, dtype=float)
    if turn_max_deg <= 0:
        return np.zeros_like(twist), np.zeros_like(twist)
    cap = np.sin(2.0 * np.radians(turn_max_deg)) * np.clip(np.minimum(s_bottom, s_top), 0.0, None)
    twist = np.clip(twist, -cap, cap)
    turn_b = 0.5 * np.arcsin(np.clip(twist / np.maximum(s_bottom, 1e-12), -1.0, 1.0))
    turn_t = -0.5 * np.arcsin(np.clip(twist / np.maximum(s_top, 1e-12), -1.0, 1.0))
    return turn_b, turn_t


def turned(direction, turn):
    """Unit directions (m, 2) turned by ``turn`` (m,) rad, counter-clockwise."""
    d = np.asarray(direction, dtype=float)
    c, s = np.cos(turn), np.sin(turn)
    return np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], axis=1)


def rest_angles(xy, faces, shrink, K, top=None):
    """Rest dihedral angle of each hinge of a sheet whose triangles have the natural
    curvature ``K``: (h,) rad, hinges as ``topology(faces).hinges``.

    xy : (n, 2) mm, the layout; shrink : (m, 2, 2) each triangle's shrink tensor in
    the layout (a sheet shrunk by ``sigma`` along ``d`` has ``sigma d d^T``); K :
    (m, 2, 2) 1/mm, symmetric, in the layout's frame after the shrink (a bilayer along
    ``d`` has ``kappa d d^T``).

    Each triangle, shrunk, is lifted onto the quadric
    ``z = (p - m)^T K (p - m) / 2`` about the hinge's midpoint ``m``: both ends of the
    edge rise alike, so the edge stays level and the triangle turns about it by the rise
    of its far corner over its height. Exact for a sheet bent to one curvature, whatever
    way the mesh runs (a centroid-to-centroid estimate is a third short on a grid).
    """
    faces = np.asarray(faces, dtype=np.int64)
    xy = np.asarray(xy, dtype=float)
    top = top or topology(faces, len(xy))
    hinges, hinge_faces = top.hinges, top.hinge_faces
    keep = np.eye(2)[None] - np.asarray(shrink, dtype=float)
    a, b = hinges[:, 0], hinges[:, 1]
    half_flat = 0.5 * (xy[b] - xy[a])
    mid = 0.5 * (xy[a] + xy[b])
    theta = np.zeros(len(hinges))
    for side in range(2):
        f = hinge_faces[:, side]
        far = xy[faces[f].sum(axis=1) - a - b] - mid
        half, far = (np.einsum("hij,hj->hi", keep[f], v) for v in (half_flat, far))
        length = np.maximum(2.0 * np.linalg.norm(half, axis=1), 1e-12)
        height = np.abs(half[:, 0] * far[:, 1] - half[:, 1] * far[:, 0]) * 2.0 / length
        rise = 0.5 * (np.einsum("hi,hij,hj->h", far, K[f], far)
                      - np.einsum("hi,hij,hj->h", half, K[f], half))
        theta += rise / np.maximum(height, 1e-12)
    return theta


def target_tensor(hf, mesh, flat, sigma, smooth_mm=PROGRAM_SMOOTH_MM, derivs=None):
    """The target's curvature (second fundamental form, positive for a dome) carried
    into each triangle's frame of :func:`rest_angles`: (m, 2, 2) 1/mm.

    The map from the shrunk layout onto the target is an isometry where the layout
    is admissible; its horizontal part ``J`` pulls the height field's Hessian back:
    ``K = -J^T H J / sqrt(1 + |grad z|^2)``. What a sheet would need to be programmed
    with to settle exactly on the target; :func:`program` can give only ``d^T K d``.
    ``derivs``: :func:`surface_derivatives` of ``hf`` at ``smooth_mm``, where a caller
    reads the same target on several layouts (smoothing the field is most of the work).
    """
    V = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    d = np.asarray(flat.direction, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    P = np.asarray(flat.xy, dtype=float)[faces]
    T = V[faces]
    sides = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]], axis=2)           # (m, 2, 2)
    along = np.einsum("mc,mck->mk", d, sides)
    sides = sides - sigma[:, None, None] * d[:, :, None] * along[:, None, :]
    J = np.stack([T[:, 1, :2] - T[:, 0, :2], T[:, 2, :2] - T[:, 0, :2]], axis=2)
    J = J @ np.linalg.inv(sides)
    derivs = derivs or surface_derivatives(hf, smooth_mm)
    fx, fy, fxx, fxy, fyy = derivs(T.mean(axis=1)[:, :2])
    H = np.stack([np.stack([fxx, fxy], axis=1), np.stack([fxy, fyy], axis=1)], axis=1)
    return -np.einsum("mji,mjk,mkl->mil", J, H, J) / np.sqrt(1 + fx * fx + fy * fy)[:, None, None]


def bend_free_directions(hf, mesh, flat, below, smooth_mm=5.0):
    """``flat`` (a :class:`pipeline.layout.free.FreeLayout`) with its free directions
    (``sigma`` below ``below``) turned toward the target's direction of strongest
    normal curvature, as far as that direction is marked (the difference of the two
    principal curvatures' sizes, relative to its 95th percentile over the sheet), and
    kept smooth (:func:`pipeline.layout.free.smooth_free_directions`)."""
    import dataclasses

    from pipeline.layout.free import smooth_free_directions
    sigma = np.asarray(flat.sigma, dtype=float)
    K = target_tensor(hf, mesh, flat, np.clip(sigma, 0.0, None), smooth_mm)
    k, v = np.linalg.eigh(K)
    big = np.abs(k[:, 1]) >= np.abs(k[:, 0])
    prefer = np.where(big[:, None], v[:, :, 1], v[:, :, 0])
    marked = np.abs(np.abs(k[:, 1]) - np.abs(k[:, 0]))
    scale = float(np.percentile(marked, 95))
    if scale <= 0:
        return flat
    d = smooth_free_directions(flat.direction, sigma, mesh.faces, below, prefer=prefer,
                               strength=np.clip(marked / scale, 0.0, 1.0))
    return dataclasses.replace(flat, direction=d)
