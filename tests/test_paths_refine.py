"""Carrying the stripe phase to finer triangles."""

import numpy as np
from scipy.spatial import Delaunay

from pipeline.paths import refine, stripes
from pipeline.paths.phase import _wrap
from pipeline.paths.sheet import Sheet

WIDTH = 0.5


def _grid(n=12, h=1.25):
    g = np.arange(n) * h
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return xy, Delaunay(xy).simplices


def test_split_triangles_carry_the_phase_along_each_side():
    """Paths straight across the sheet (a phase linear in y, two and a half periods
    along a side) keep their phase at every new midpoint."""
    xy, faces = _grid()
    X = np.tile([0.0, 1.0], (len(xy), 1))
    phase = _wrap(2 * np.pi * xy[:, 1] / WIDTH)
    red = np.zeros(len(faces), bool)
    red[::3] = True
    xy2, faces2, ph2, X2, parent = refine.split(xy, faces, phase, X, WIDTH, red)
    assert len(xy2) > len(xy) and np.array_equal(ph2[:len(xy)], phase)
    want = _wrap(2 * np.pi * xy2[:, 1] / WIDTH)
    assert np.allclose(np.cos(ph2 - want), 1.0)
    # Every triangle lies inside the one it came from, and the areas add up.
    area = np.abs(stripes.signed_areas_2d(xy2, faces2))
    assert np.allclose(np.bincount(parent, area, len(faces)),
                       np.abs(stripes.signed_areas_2d(xy, faces)))
    assert set(np.unique(faces2)) == set(range(len(xy2)))


def test_forks_are_split_until_their_bare_patch_is_a_sixteenth():
    """A field with curl forks the stripes; after refining, every bare triangle is a
    sixteenth or less of a layout triangle (quartered by the global split and twice
    more where the phase still winds)."""
    xy, faces = _grid()
    c = xy[faces].mean(axis=1)
    a = 0.6 * np.sin(2 * np.pi * c[:, 0] / 6)
    normal = np.stack([-np.sin(a), np.cos(a)], axis=1)
    phase, X = stripes.stripe_phase(Sheet(xy, faces), normal, WIDTH)
    _, bare0 = stripes.corner_phases(xy, faces, phase, X, WIDTH)
    assert (bare0 > 0).sum() > 5
    xy2, faces2, _, _, parent, _, bare = refine.refine_phase(Sheet(xy, faces), normal, phase, X,
                                                           WIDTH)
    small = np.abs(stripes.signed_areas_2d(xy, faces)).min() / 64 * 1.001
    assert bare.any() and np.all(np.abs(stripes.signed_areas_2d(xy2, faces2[bare > 0])) <= small)


def test_each_triangle_side_is_numbered_as_its_edge():
    """The sides a split halves are numbered once for the whole mesh, in the order of
    ``unique_edges``: side k of a triangle, from corner k to k + 1, is that edge."""
    from pipeline.geometry import face_sides, unique_edges
    xy, faces = _grid()
    sides, edges = face_sides(faces)
    pairs = [np.sort(np.stack([faces[:, k], faces[:, (k + 1) % 3]], axis=1), axis=1)
             for k in range(3)]
    want, count = np.unique(np.concatenate(pairs), axis=0, return_counts=True)
    assert np.array_equal(edges, want) and np.array_equal(unique_edges(faces), want)
    assert np.array_equal(unique_edges(faces, return_counts=True)[1], count)
    for k in range(3):
        assert np.array_equal(edges[sides[:, k]], pairs[k])
    assert [len(a) for a in face_sides(np.zeros((0, 3), int))] == [0, 0]
