"""Tool paths (paper 6.3): continuous, equally spaced, covering the flat sheet."""

import numpy as np
import pytest
import shapely

from conftest import reference_toolpaths
from pipeline.paths.stats import coverage_grid, isoline_angles
from pipeline.paths.isoline import boundary_loop, merge_collinear, path_field, plan_toolpaths

PW = 0.48


@pytest.mark.parametrize("name", ["dome", "saddle", "starfish"])
def test_paths_are_equally_spaced_and_cover_the_sheet(name):
    _, _, tp = reference_toolpaths(name)
    s = tp.info["spacing_mm"]
    assert s["target"] == PW
    assert 0.8 * PW <= s["p05"] and s["p95"] <= 1.2 * PW, s
    assert tp.info["coverage"] > 0.95
    assert tp.info["overlap"] < 0.05


def test_overlap_counts_nodes_two_paths_reach_however_densely_one_is_sampled():
    """Path A (y = 0) has a vertex every 0.01 mm, as chained isoline pieces can;
    path B (y = 0.3) one every 0.125 mm. A node between them is covered twice
    although dozens of A's samples are nearer than any of B's (a query for a
    node's few nearest samples sees only A there)."""
    pw = 0.5
    xa = np.arange(0.0, 10.0 + 1e-9, 0.01)
    xb = np.arange(0.0, 10.0 + 1e-9, 0.125)
    samples = np.vstack([np.column_stack([xa, np.zeros_like(xa)]),
                         np.column_stack([xb, np.full_like(xb, 0.3)])])
    label = np.repeat([0, 1], [len(xa), len(xb)])
    box = shapely.box(-0.5, -0.5, 10.5, 0.8)
    corners = np.array([[-0.5, -0.5], [10.5, 0.8]])
    covered, twice = coverage_grid(samples, label, corners, box, pw)
    # The grid as documented, and each node's distance to either path's samples.
    res = pw / 2.5
    gx = np.arange(-0.5, 10.5, res) + res / 2
    gy = np.arange(-0.5, 0.8, res) + res / 2
    X, Y = np.meshgrid(gx, gy)
    nodes = np.column_stack([X.ravel(), Y.ravel()])
    nodes = nodes[shapely.contains_xy(box, nodes[:, 0], nodes[:, 1])]
    da = np.min(np.hypot(*(nodes[:, None, :] - samples[None, label == 0]).transpose(2, 0, 1)), axis=1)
    db = np.min(np.hypot(*(nodes[:, None, :] - samples[None, label == 1]).transpose(2, 0, 1)), axis=1)
    assert len(covered) == len(nodes)
    np.testing.assert_array_equal(covered, np.minimum(da, db) <= pw / 2)
    np.testing.assert_array_equal(twice, (da < 0.999 * pw / 2) & (db < 0.999 * pw / 2))
    assert twice.sum() == 51  # the row y = 0.1 from x = 0 to 10 mm


def test_dome_is_one_continuous_trace_without_sharp_turns():
    _, _, tp = reference_toolpaths("dome")
    assert tp.info["traces"] == 1
    assert tp.info["travel_moves"] == 0
    assert tp.info["sharp_turns"] == 0
    # Concentric isolines admit equally spaced paths exactly along them.
    assert tp.info["isoline_angle_deg"]["p95"] < 1.0, tp.info["isoline_angle_deg"]


def test_isoline_angle_is_the_angle_between_paths_and_isolines():
    # Isolines x = const; paths u = const on lines turned 10 degrees (or 170: the
    # sense of a path does not matter, its direction does).
    g = np.linspace(0.0, 10.0, 11)
    X, Y = np.meshgrid(g, g)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    i = np.arange(121).reshape(11, 11)
    a, b, c, d = i[:-1, :-1], i[:-1, 1:], i[1:, :-1], i[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                            np.stack([a, d, c], -1).reshape(-1, 3)])
    level = xy[:, 0]
    for turn_deg in (10.0, 170.0):
        t = np.radians(turn_deg)
        u = (xy @ [np.cos(t), np.sin(t)]) / 0.5
        angle, path_mm = isoline_angles(xy, faces, level, u)
        np.testing.assert_allclose(angle, 10.0, atol=1e-9)
        # path length per face: area x level sets per mm (here 2 per mm)
        np.testing.assert_allclose(path_mm, 0.5 * 2.0, rtol=1e-9)


def test_two_peaks_need_few_traces():
    # One trace per peak region: a saddle splits the paths into two nests of loops.
    _, _, tp = reference_toolpaths("saddle")
    assert 2 <= tp.info["traces"] <= 4


@pytest.mark.parametrize("name", ["dome", "saddle"])
def test_paths_stay_inside_the_flat_footprint(name):
    mesh, flat, tp = reference_toolpaths(name)
    outline = shapely.Polygon(flat.xy[boundary_loop(mesh.faces)])
    pts = np.concatenate(tp.traces)
    inside = shapely.contains_xy(outline.buffer(1e-6), pts[:, 0], pts[:, 1])
    assert inside.all()


def test_segments_carry_the_shrink_of_the_printing_edges():
    _, flat, tp = reference_toolpaths("dome")
    sig = np.concatenate(tp.sigma)
    assert len(sig) == sum(len(t) - 1 for t in tp.traces)
    # Same range as the printing edges (interpolation cannot leave it).
    assert sig.min() >= flat.sigma.min() - 1e-9 and sig.max() <= flat.sigma.max() + 1e-9
    # On a dome shrink grows outward: outer paths shrink more than inner ones.
    pts = np.concatenate([t[:-1] for t in tp.traces])
    r = np.linalg.norm(pts - pts.mean(axis=0), axis=1)
    assert np.corrcoef(r, sig)[0, 1] > 0.8


def test_path_index_field_on_a_flat_disc_counts_path_widths():
    # A flat disc whose isolines are circles: the path index grows by 1 per width.
    n_r, n_t = 40, 120
    r = np.linspace(1.0, 20.0, n_r)
    t = np.linspace(0, 2 * np.pi, n_t, endpoint=False)
    R, T = np.meshgrid(r, t, indexing="ij")
    xy = np.column_stack([(R * np.cos(T)).ravel(), (R * np.sin(T)).ravel()])
    level = -R.ravel()                      # rises toward the centre
    idx = np.arange(n_r * n_t).reshape(n_r, n_t)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)
    c, d = idx[1:], np.roll(idx[1:], -1, axis=1)
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                            np.stack([a, d, c], -1).reshape(-1, 3)])
    # Counter-clockwise in the plane.
    a, b = xy[faces[:, 1]] - xy[faces[:, 0]], xy[faces[:, 2]] - xy[faces[:, 0]]
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    faces[cross < 0] = faces[cross < 0][:, ::-1]
    u = path_field(xy, faces, level, 0.5)
    assert u.reshape(n_r, n_t)[0].mean() - u.reshape(n_r, n_t)[-1].mean() == \
        pytest.approx(19.0 / 0.5, rel=0.01)
    tp = plan_toolpaths(xy, faces, level, np.zeros((0, 2), int), np.zeros(0), 0.5)
    assert tp.info["spacing_mm"]["p50"] == pytest.approx(0.5, rel=0.02)
    assert tp.info["traces"] == 1


def test_collinear_segments_merge_unless_shrink_differs():
    pts = np.column_stack([np.linspace(0, 10, 41), np.zeros(41)])
    sig = np.full(40, 0.1)
    p, s = merge_collinear(pts, sig, 2.0, 0.005)
    assert len(p) == 2 and s == pytest.approx([0.1])
    sig[20:] = 0.2
    p, s = merge_collinear(pts, sig, 2.0, 0.005)
    assert len(p) == 3 and s == pytest.approx([0.1, 0.2])
    bent = pts.copy()
    bent[20:, 1] = (bent[20:, 0] - 5.0) * 0.2   # an 11 degree bend at x = 5
    p, _ = merge_collinear(bent, np.full(40, 0.1), 2.0, 0.005)
    assert len(p) == 3


def test_merged_shrink_is_the_length_weighted_mean():
    # 1 mm at 0.100 then 3 mm at 0.104 (within the 0.005 tolerance), then a run apart.
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [4.0, 0.0], [6.0, 0.0]])
    p, s = merge_collinear(pts, np.array([0.100, 0.104, 0.2]), 2.0, 0.005)
    assert np.array_equal(p, pts[[0, 2, 3]])
    assert s == pytest.approx([0.103, 0.2], abs=1e-12)


def test_path_samples_of_all_paths_at_once_are_those_of_each_path():
    """The samples the figures are measured on, made for thousands of stripe pieces in
    one pass: the same points, in the same order, as path by path (end points kept)."""
    from pipeline.paths.samples import _densify, sample_tree
    rng = np.random.default_rng(0)
    paths = [np.cumsum(rng.normal(size=(rng.integers(2, 9), 2)), axis=0) for _ in range(40)]
    samples, label, tree = sample_tree(paths, 0.12)
    each = [_densify(p, 0.12) for p in paths]
    assert np.array_equal(samples, np.concatenate(each))
    assert np.array_equal(label, np.repeat(np.arange(len(paths)), [len(q) for q in each]))
    assert tree.n == len(samples)
