"""The free method's plain triangulation: its edge follows the footprint, so stripe
paths meet a smooth edge instead of a staircase."""

import numpy as np
import pytest

from pipeline.geometry import boundary_loops, signed_areas_2d
from pipeline.input import shapes
from pipeline.meshing.grid import build_grid_mesh
from pipeline.paths.stripes import stripe_toolpaths


def _disk_mesh(diameter_mm=80.0):
    hf = shapes.dome(diameter_mm=diameter_mm, height_mm=10.0)
    mesh = build_grid_mesh(hf, 1.0)
    inside = np.isfinite(hf.z)
    rows, cols = np.nonzero(inside)
    centre = np.array([cols.mean(), hf.z.shape[0] - 1 - rows.mean()]) * hf.pixel_mm
    return hf, mesh, centre


def test_the_edge_of_a_disk_lies_on_its_circle():
    hf, mesh, centre = _disk_mesh()
    r = np.linalg.norm(mesh.vertices[:, :2] - centre, axis=1)
    edge = np.unique(np.concatenate(boundary_loops(mesh.faces)))
    # The outermost footprint pixels' centres lie within half a pixel of one circle.
    assert np.ptp(r[edge]) < 2 * hf.pixel_mm
    assert r[edge].min() > r.max() - 2 * hf.pixel_mm


@pytest.mark.parametrize("name", ["dome", "starfish", "three_islands", "terrain_tile"])
def test_following_the_edge_turns_no_triangle_over(name):
    hf = {**shapes.REFERENCE, **shapes.SADDLES}[name]()
    mesh = build_grid_mesh(hf, 1.0)
    area = signed_areas_2d(mesh.vertices, mesh.faces)
    assert area.min() > 0.05 * 0.5
    assert len(boundary_loops(mesh.faces)) == 1
    # The mesh still covers the footprint (to a grid square along its edge).
    covered = area.sum() / (np.isfinite(hf.z).sum() * hf.pixel_mm ** 2)
    assert 0.97 < covered < 1.01


def test_concentric_paths_on_a_grid_disk_are_one_trace():
    _, mesh, centre = _disk_mesh()
    xy = mesh.vertices[:, :2]
    c = xy[mesh.faces].mean(axis=1) - centre
    d = np.stack([-c[:, 1], c[:, 0]], 1) / np.linalg.norm(c, axis=1)[:, None]
    tp = stripe_toolpaths(xy, mesh.faces, d, np.full(len(mesh.faces), 0.2), 0.5)
    # A staircase edge cut the outer rings into stubs a millimetre long, each a trace.
    assert tp.info["traces"] <= 2
    assert tp.info["coverage"] > 0.97
