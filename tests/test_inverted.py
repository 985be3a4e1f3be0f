"""Regions of the simulated sheet that settled inverted: found, sized, and reported."""

import numpy as np

from pipeline.geometry import HeightField
from pipeline.meshing.grid import build_grid_mesh
from pipeline.simulation.inverted import inverted_regions


def _two_hills():
    """A 100 x 60 mm sheet with two hills 8 mm high, 30 mm apart: (mesh, hill (n,) bool
    of the right hill's vertices, and its bump height (n,))."""
    y, x = np.mgrid[0:121, 0:201] * 0.5
    hill = lambda cx: 8.0 * np.exp(-((x - cx) ** 2 + (y - 30) ** 2) / (2 * 8.0 ** 2))
    mesh = build_grid_mesh(HeightField(hill(35.0) + hill(65.0) + 5.0, 0.5), 1.0)
    V = mesh.vertices
    right = 8.0 * np.exp(-((V[:, 0] - 65) ** 2 + (V[:, 1] - 30) ** 2) / (2 * 8.0 ** 2))
    return mesh, right


def test_a_hill_that_came_out_as_a_pit_is_one_inverted_region():
    mesh, right = _two_hills()
    popped = mesh.vertices.copy()
    popped[:, 2] -= 2 * right                      # the right hill, mirrored into a pit
    found = inverted_regions(mesh.vertices, popped, mesh.faces)
    assert found["regions"] == 1
    # About the hill: its crown and its skirt (within two widths of its top).
    hill = np.pi * (2 * 8.0) ** 2
    assert 0.5 * hill < found["largest_mm2"] < 2 * hill
    cx = mesh.vertices[mesh.faces[found["faces"]]].mean(axis=(0, 1))
    assert abs(cx[0] - 65) < 5 and abs(cx[1] - 30) < 3          # the right hill


def test_a_sheet_that_settled_the_right_way_has_none():
    mesh, right = _two_hills()
    near = mesh.vertices + np.random.default_rng(0).normal(0, 0.05, mesh.vertices.shape)
    near[:, 2] -= 0.3 * right                       # lower, but still a hill
    found = inverted_regions(mesh.vertices, near, mesh.faces)
    assert found["regions"] == 0 and found["area_fraction"] == 0.0


def test_inverted_regions_are_reported_and_warned_of():
    """The report's figures (no triangle mask), and a warning naming the picture."""
    from pipeline.simulation import inverted
    mesh, right = _two_hills()
    popped = mesh.vertices.copy()
    popped[:, 2] -= 2 * right

    class Sim:
        vertices, faces, target = popped, mesh.faces, mesh.vertices
    found = inverted.settled_inverted(Sim, mesh)
    assert inverted.report(found) == {"regions": 1, "area_fraction": found["area_fraction"],
                                      "largest_mm2": found["largest_mm2"]}
    (warning,) = inverted.problems(found, "hills")
    assert warning["code"] == "simulate.inverted" and "hills.preview.png" in warning["fix"]
    assert inverted.problems(inverted_regions(mesh.vertices, mesh.vertices, mesh.faces),
                             "hills") == []


def test_a_lone_inverted_point_beside_an_inverted_hill_is_no_region():
    """A single point popped the wrong way (the left hill's top) makes no region of its
    own, whatever the order of the triangles (its faces last here: once an error)."""
    mesh, right = _two_hills()
    popped = mesh.vertices.copy()
    popped[:, 2] -= 2 * right
    top = np.argmin(np.linalg.norm(mesh.vertices[:, :2] - [35, 30], axis=1))
    popped[top, 2] -= 16.0
    order = np.argsort(-np.linalg.norm(mesh.vertices[mesh.faces].mean(axis=1)[:, :2]
                                       - [35, 30], axis=1))
    found = inverted_regions(mesh.vertices, popped, mesh.faces[order])
    assert found["regions"] == 1


def test_the_preview_hatches_the_inverted_region_and_only_it(tmp_path):
    from pipeline.pictures import render
    from pipeline.pictures.figure import INVERTED
    mesh, right = _two_hills()
    popped = mesh.vertices.copy()
    popped[:, 2] -= 2 * right
    found = inverted_regions(mesh.vertices, popped, mesh.faces)
    disp = np.linalg.norm(popped - mesh.vertices, axis=1)

    def blue(img, cols):
        a = np.asarray(img).astype(int)[:, cols]
        return (np.abs(a - np.array(INVERTED)) < 60).all(axis=2) & (a[..., 2] > a[..., 0] + 80)
    kw = dict(panel_px=(400, 300), azimuth_deg=0, elevation_deg=60, contour_mm=None)
    img = render.preview_image(mesh.vertices, mesh.faces, popped, disp,
                               inverted_faces=found["faces"], **kw)
    plain = render.preview_image(mesh.vertices, mesh.faces, popped, disp, **kw)
    # The simulated panel is the right one: its left half holds the right way hill, its
    # right half the one that came out as a pit.
    assert blue(img, slice(600, 780)).sum() > 300
    assert blue(img, slice(420, 590)).sum() < 10
    assert blue(plain, slice(0, plain.width)).sum() < 10
