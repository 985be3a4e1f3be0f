"""A mesh's top surface as a height field, read whichever way up it was exported.

Tools disagree on which axis is up: Blender writes OBJ with +Y up, CAD and most STL
exports keep +Z. A Y-up hemisphere read with Z up is a wall, not a dome; so the up
direction is the one of the six axis directions along which the surface is a
single-valued height field seen from that side: the least share of its area (projected
along the direction, ``area * |n . d|``) faces away from it. A flat base at the
lowest level (a terrain block's bottom) and walls (normals across ``d``) add nothing;
ties go to +Z. The sidecar's ``up`` overrides the choice. A mesh that faces away
from every direction by more than :data:`FACING_AWAY_MAX` (a closed solid, an
overhang, a shell with its faces wound every which way) is refused
(``heightfield.not_a_heightfield``) with its share and the fix.
"""

import numpy as np

from pipeline.pictures.raster import pixel_barycentrics, rasterize_triangles

# Grid pitch for meshes without pixel_mm: about the paper's path width.
MESH_PIXEL_MM = 0.5

# The share of the surface (projected along up) that may face away: the ragged edge of
# a surface cut from a closed model, or a scan's few folded triangles. A closed solid
# faces away by half in every direction.
FACING_AWAY_MAX = 0.02

# Axis names in the sidecar's terms -> unit vector.
DIRECTIONS = {"z": (0, 0, 1), "y": (0, 1, 0), "x": (1, 0, 0),
              "-z": (0, 0, -1), "-y": (0, -1, 0), "-x": (-1, 0, 0)}


def facing_away(vertices, faces):
    """Per axis direction, the share of the surface facing away from it.

    vertices : (n, 3) float; faces : (m, 3) int. A face counts with its area projected
    along the direction (walls count for nothing); faces all at the lowest level along
    the direction and facing straight away (a flat base) are left out. Returns
    {name: share in 0..1} over :data:`DIRECTIONS`.
    """
    v = np.asarray(vertices, dtype=float)
    tri = v[np.asarray(faces, dtype=np.int64)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # 2 * area * n
    span = max(float(np.ptp(v, axis=0).max()), 1e-12)
    out = {}
    for name, d in DIRECTIONS.items():
        d = np.asarray(d, float)
        proj = cross @ d
        height = tri @ d
        base = (np.abs(height - height.min()).max(axis=1) < 1e-6 * span) & (
            proj < -0.999 * np.linalg.norm(cross, axis=1))
        proj = np.where(base, 0.0, proj)
        total = np.abs(proj).sum()
        out[name] = float(-proj[proj < 0].sum() / total) if total > 0 else 1.0
    return out


def choose_up(shares, asked=None):
    """The up direction: ``asked`` (a sidecar's ``up``) or the least facing away,
    ties (within a thousandth) to +Z in the order of :data:`DIRECTIONS`. Returns name."""
    if asked:
        return asked.lstrip("+")
    best = min(shares.values())
    return next(name for name in DIRECTIONS if shares[name] <= best + 1e-3)


def turned_up(vertices, up):
    """``vertices`` (n, 3) turned so ``up`` points along +Z: a proper rotation (the
    footprint is seen from above, never mirrored)."""
    x, y, z = np.asarray(vertices, dtype=float).T
    turned = {"z": (x, y, z), "-z": (x, -y, -z), "y": (x, -z, y), "-y": (x, z, -y),
              "x": (-z, y, x), "-x": (z, y, -x)}[up]
    return np.column_stack(turned)


def orientation(vertices, faces, asked, fail):
    """The up direction of a mesh and the report's ``heightfield.up``: ``(name, {"up",
    "chosen": "sidecar" | "auto", "facing_away": share along up, "facing_away_by_axis"})``.
    ``fail(code, message, fix, **details)`` builds the refusal of a mesh that is no
    height field along any axis (only when none was asked for)."""
    shares = facing_away(vertices, faces)
    up = choose_up(shares, asked)
    if not asked and shares[up] > FACING_AWAY_MAX:
        raise fail("heightfield.not_a_heightfield",
                   "the mesh is no height field along any axis: seen from its best side (%s) "
                   "%.0f %% of its surface faces away (a closed solid faces away by half, an "
                   "overhang by its underside)" % (_signed(up), 100 * shares[up]),
                   "export only the top surface (delete the underside and any overhang), "
                   "or check that its faces are wound consistently; if the side it faces is "
                   "known, write `up: z` (or x, y, -x, -y, -z) in the sidecar to take the "
                   "surface seen from there",
                   facing_away={k: round(s, 4) for k, s in shares.items()})
    return up, {"up": _signed(up), "chosen": "sidecar" if asked else "auto",
                "facing_away": round(shares[up], 4),
                "facing_away_by_axis": {_signed(k): round(s, 4) for k, s in shares.items()}}


def _signed(name):
    return name if name.startswith("-") else "+" + name


def top_surface(verts, faces, pixel_mm, max_pixels, too_many, colors=None):
    """A z-buffer of the mesh seen from +Z: heights (rows, cols) mm, NaN outside, row 0
    north, and colour (rows, cols, 3) uint8 or None. ``too_many(rows, cols)`` builds the
    refusal of a grid over ``max_pixels``."""
    lo, hi = verts[:, :2].min(axis=0), verts[:, :2].max(axis=0)
    cols, rows = (np.floor((hi - lo) / pixel_mm + 1e-9).astype(int) + 1)
    if rows * cols > max_pixels:
        raise too_many(rows, cols)
    # One ray straight down per sample, first hit kept. The rasteriser samples pixel
    # centres (+0.5); our samples sit on grid points.
    xy = np.column_stack([(verts[:, 0] - lo[0]) / pixel_mm + 0.5,
                          (hi[1] - verts[:, 1]) / pixel_mm + 0.5])
    face_id = rasterize_triangles(xy, -verts[:, 2], faces, (rows, cols))
    r, c, face, w = pixel_barycentrics(xy, faces, face_id)
    corners = faces[face]
    z = np.full((rows, cols), np.nan)
    z[r, c] = np.einsum("ij,ij->i", w, verts[corners, 2])
    color = None
    if colors is not None:
        color = np.zeros((rows, cols, 3), np.uint8)
        rgb = np.einsum("ij,ijk->ik", w, colors[corners])
        color[r, c] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    return z, color


def vertex_colors(mesh):
    """(n, 3) vertex colours of a trimesh from vertex or texture visuals, or None."""
    visual = getattr(mesh, "visual", None)
    try:
        kind = visual.kind if visual is not None else None
        if kind == "texture":
            visual = visual.to_color()
            kind = visual.kind
        if kind == "vertex":
            c = np.asarray(visual.vertex_colors)
            if c.shape[0] == len(mesh.vertices) and not (c[:, :3] == c[0, :3]).all():
                return c[:, :3].astype(np.float64)
    except Exception:  # colour is optional; a broken texture must not block the heights
        return None
    return None
