"""The isoline mesher over seeded random terrains (the regression net of
``test_mesh_sweep_*``; split in four tests of 50 so two workers share the 200 seeds)."""

import numpy as np

from pipeline.geometry import face_areas


def _edges(faces):
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def pieces(faces):
    """How many pieces the triangles make, joined by their edges."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    n = int(faces.max()) + 1
    return connected_components(sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])),
                                              shape=(n, n)), directed=False)[0]


def sweep(seeds):
    """Meshes ``random_terrain(seed)`` for each seed at the shipped mesh spacing.

    Returns ``(overlaps, twice, holed, meshed)``: the seeds that raised
    ``mesh.overlap``, that meshed into more than one piece or not covering the
    footprint once, that are not a disk (Euler characteristic != 1), and how many
    meshed at all (the others raised a documented error)."""
    from pipeline.errors import PipelineError
    from pipeline.input.simplify import simplify
    from pipeline.input.validate import validate
    from pipeline.meshing.isoline import build_mesh
    from pipeline.profiles.profile import load_profile
    from terrains import random_terrain
    mp = load_profile("generic-0.5mm").mesh
    overlaps, twice, holed, meshed = [], [], [], 0
    for seed in seeds:
        try:
            hf, _ = validate(random_terrain(seed), 5.0)
            hf, _ = simplify(hf, 2.0, 1.0)
            m = build_mesh(hf, isoline_step_mm=mp.isoline_step_mm, l_u_mm=mp.l_u_mm,
                           gradient_spacing_mm=mp.gradient_spacing_mm)
        except PipelineError as e:
            if e.code == "mesh.overlap":
                overlaps.append(seed)
            continue
        meshed += 1
        area = face_areas(m.vertices[:, :2], m.faces).sum()
        if pieces(m.faces) != 1 or abs(area / (np.isfinite(hf.z).sum() * hf.pixel_mm ** 2)
                                        - 1) > 0.005:
            twice.append(seed)
        if len(m.vertices) - len(_edges(m.faces)) + len(m.faces) != 1:
            holed.append(seed)
    return overlaps, twice, holed, meshed
