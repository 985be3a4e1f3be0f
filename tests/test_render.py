"""Pictures and mesh files: colour maps, the rasteriser, the four images, PLY round trip."""

import colorsys
import io
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from pipeline.input import shapes
from pipeline.pictures import hfimage, render
from pipeline.pictures.figure import INVALID_HIGH, INVALID_LOW
from pipeline.plyio import write_ply
from pipeline.pictures.raster import draw_segments, pixel_barycentrics, rasterize_triangles
from pipeline.pictures.render import colormap

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def grid_mesh(hf, step=1):
    """Triangulate the grid samples inside a height field's footprint: (vertices, faces)."""
    z = hf.z[::step, ::step]
    ok = np.isfinite(z)
    idx = np.full(z.shape, -1)
    idx[ok] = np.arange(ok.sum())
    rr, cc = np.nonzero(ok)
    v = np.column_stack([hf.xy(rr * step, cc * step), z[ok]])
    nw, ne, sw, se = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    f = np.concatenate([np.stack([sw, se, ne], -1).reshape(-1, 3),
                        np.stack([sw, ne, nw], -1).reshape(-1, 3)])
    return v, f[(f >= 0).all(1)]


def rgb_at(img, xy_mm):
    """Pixel colour at a point given in mm, through the image's recorded transform."""
    s = img.info["px_per_mm"]
    ox, oy = img.info["origin_px"]
    x, y = ox + s * xy_mm[0], oy - s * xy_mm[1]
    return np.asarray(img.convert("RGB"))[int(np.floor(y)), int(np.floor(x))].astype(int)


def not_blank(img, min_colors=50):
    a = np.asarray(img.convert("RGB"))
    return a.std() > 10 and len(np.unique(a.reshape(-1, 3), axis=0)) >= min_colors


# --- colour maps -----------------------------------------------------------------------------

def test_shrink_colormap_runs_blue_to_red_with_monotonic_hue():
    c = colormap(np.linspace(0.0, 0.343, 256), 0.0, 0.343, "shrink").astype(int)
    lo, hi = c[0], c[-1]
    assert lo[2] > lo[0] + 100 and hi[0] > hi[2] + 100  # blue at s_min, red at s_max
    hue = np.array([colorsys.rgb_to_hsv(*(p / 255.0))[0] for p in c]) * 360
    assert np.all(np.diff(hue) <= 1e-6), "hue must fall monotonically from blue to red"
    assert hue[0] > 200 and hue[-1] < 15


def test_displacement_colormap_darkens_monotonically_and_clips():
    vals = np.linspace(0, 3, 200)
    c = colormap(vals, 0.0, 3.0, "displacement").astype(float)
    luma = c @ [0.2126, 0.7152, 0.0722]
    assert np.all(np.diff(luma) < 0)
    out = colormap(np.array([-5.0, 0.0, 3.0, 99.0, np.nan]), 0.0, 3.0, "displacement")
    assert (out[0] == out[1]).all() and (out[2] == out[3]).all()
    assert out.dtype == np.uint8 and out.shape == (5, 3)
    assert len(set(map(tuple, out[4:]))) == 1 and out[4][0] == out[4][1] == out[4][2]  # NaN grey


# --- rasteriser ------------------------------------------------------------------------------

def test_rasterizer_covers_exactly_the_pixel_centres_inside_a_triangle():
    xy = np.array([[2.0, 2.0], [18.0, 2.0], [2.0, 18.0]])
    fid = rasterize_triangles(xy, np.zeros(3), [[0, 1, 2]], (20, 24))
    r, c = np.mgrid[0:20, 0:24]
    x, y = c + 0.5, r + 0.5
    inside = (x >= 2) & (y >= 2) & (x + y <= 20)
    assert fid.shape == (20, 24)
    assert ((fid == 0) == inside).all()
    assert (fid[~inside] == -1).all()


def test_rasterizer_depth_test_nearer_triangle_wins_in_either_order():
    big = [[0.0, 0.0], [30.0, 0.0], [0.0, 30.0]]
    xy = np.array(big + big)
    depth = np.array([5.0, 5.0, 5.0, 1.0, 1.0, 1.0])  # second triangle nearer
    a = rasterize_triangles(xy, depth, [[0, 1, 2], [3, 4, 5]], (30, 30))
    b = rasterize_triangles(xy, depth, [[3, 4, 5], [0, 1, 2]], (30, 30))
    assert (a[a >= 0] == 1).all() and (b[b >= 0] == 0).all()
    # Two crossing tilted planes: depth is per pixel, so each wins on its near side.
    xy = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 10.0], [40.0, 10.0]])
    near_left = np.array([0.0, 10.0, 0.0, 10.0])
    near_right = 10.0 - near_left
    v = np.concatenate([xy, xy])
    faces = [[0, 1, 3], [0, 3, 2], [4, 5, 7], [4, 7, 6]]
    fid = rasterize_triangles(v, np.concatenate([near_left, near_right]), faces, (10, 40))
    assert (fid[:, :18] <= 1).all() and (fid[:, 22:] >= 2).all()


def test_pixel_barycentrics_interpolate_a_linear_function_exactly():
    xy = np.array([[1.0, 1.0], [30.0, 4.0], [6.0, 25.0]])
    fid = rasterize_triangles(xy, np.zeros(3), [[0, 1, 2]], (30, 32))
    rows, cols, face, w = pixel_barycentrics(xy, np.array([[0, 1, 2]]), fid)
    f = lambda x, y: 2 * x - 3 * y + 1
    got = w @ f(xy[:, 0], xy[:, 1])
    assert len(rows) > 200 and (face == 0).all()
    assert np.allclose(got, f(cols + 0.5, rows + 0.5), atol=1e-9)


def test_segments_are_drawn_where_expected_and_priority_wins_crossings():
    canvas = np.full((21, 41, 3), 255.0)
    draw_segments(canvas, [[5.0, 10.5]], [[35.0, 10.5]], (200, 0, 0), 3.0)
    assert np.allclose(canvas[9:12, 8:33], [200, 0, 0])  # 3 px wide, fully covered
    assert np.allclose(canvas[7, :], 255) and np.allclose(canvas[13, :], 255)
    assert np.allclose(canvas[10, 0:3], 255) and np.allclose(canvas[10, 38:], 255)  # round caps end
    canvas = np.full((21, 41, 3), 255.0)
    draw_segments(canvas, [[5.0, 10.5], [20.5, 0.0]], [[35.0, 10.5], [20.5, 21.0]],
                  np.array([[200, 0, 0], [0, 0, 200]]), 3.0, priority=[0, 1])
    assert np.allclose(canvas[10, 20], [0, 0, 200])


# --- stress image ----------------------------------------------------------------------------

def _strip_layout():
    """A 100 x 20 mm sheet: 11 horizontal isolines 2 mm apart, 10 mm printing edges."""
    xs, ys = np.arange(0, 101, 10.0), np.arange(0, 21, 2.0)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    nx = len(xs)
    idx = np.arange(len(xy)).reshape(len(ys), nx)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                            np.stack([a, d, c], -1).reshape(-1, 3)])
    pe = np.concatenate([np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1)])
    return xy, faces, pe


def test_stress_image_colours_edges_by_sigma_marks_invalid_ones_and_has_a_legend():
    xy, faces, pe = _strip_layout()
    sigma = np.full(len(pe), 0.10)
    mid = (xy[pe[:, 0]] + xy[pe[:, 1]]) / 2
    high = np.flatnonzero(np.isclose(mid[:, 1], 10) & np.isclose(mid[:, 0], 75))[0]
    low = np.flatnonzero(np.isclose(mid[:, 1], 4) & np.isclose(mid[:, 0], 25))[0]
    sigma[high], sigma[low] = 0.50, -0.05
    img = render.stress_image(xy, pe, sigma, 0.0, 0.343, faces=faces, px_per_mm=8, title="strip")
    expected = colormap([0.10], 0.0, 0.343, "shrink")[0].astype(int)
    assert np.abs(rgb_at(img, (35.0, 16.0)) - expected).max() <= 3
    assert np.abs(rgb_at(img, mid[high]) - INVALID_HIGH).max() <= 3
    assert np.abs(rgb_at(img, mid[low]) - INVALID_LOW).max() <= 3
    # Between isolines lies a pale tint of the same colour, not the edge colour itself.
    luma = lambda c: np.dot(c, [0.2126, 0.7152, 0.0722])
    tint = rgb_at(img, (35.0, 17.0))
    assert luma(tint) > luma(expected) + 40 and tint[2] > tint[0]
    # Legend: right of the drawing, the full colour bar from s_min to s_max plus the swatches.
    a = np.asarray(img)
    right = a[:, int(img.info["origin_px"][0] + 8 * 100 + 20):].reshape(-1, 3).astype(int)
    for color in colormap([0.0, 0.1715, 0.343], 0.0, 0.343, "shrink").astype(int):
        assert (np.abs(right - color).max(1) <= 3).any()
    assert (np.abs(right - INVALID_HIGH).max(1) <= 3).sum() > 20
    assert img.width > 8 * 100 and img.height > 8 * 20


def test_a_free_layouts_sheet_is_tinted_by_each_triangles_shrink():
    """Its strokes (a print direction per triangle) share no edge with the faces, so the
    tint comes from the layout's own shrink per triangle: the less shrunk half of the
    sheet pale blue, the more shrunk one warmer, not one grey for both."""
    xy, faces, _ = _strip_layout()
    centre_x = xy[faces].mean(axis=1)[:, 0]
    sigma = np.where(centre_x < 50, 0.05, 0.30)
    img = render.direction_image(xy, faces, np.tile([1.0, 0.0], (len(faces), 1)), sigma,
                                 0.0, 0.343, px_per_mm=8)
    tint = 0.28 * colormap([0.05, 0.30], 0.0, 0.343, "shrink") + 0.72 * 246.0
    for at, expected in (((19.5, 4.3), tint[0]), ((79.5, 4.3), tint[1])):
        assert np.abs(rgb_at(img, at) - expected).max() <= 3, (at, rgb_at(img, at), expected)
    assert np.abs(tint[0] - tint[1]).max() > 20


def test_stress_image_respects_max_px_and_default_scale():
    xy, faces, pe = _strip_layout()
    small = render.stress_image(xy * 10, pe, np.full(len(pe), 0.2), 0.0, 0.343, max_px=500)
    assert small.info["px_per_mm"] <= 500 / 1000 + 1e-9
    assert not_blank(small, 20)


# --- preview, tool paths, height field, montage ----------------------------------------------

@pytest.fixture(scope="module")
def dome_mesh():
    return grid_mesh(shapes.dome(diameter_mm=80, height_mm=20, pixel_mm=1.0))


def test_preview_shows_target_neutral_and_simulated_coloured_by_displacement(dome_mesh):
    v, f = dome_mesh
    sim = v.copy()
    sim[:, 2] *= 0.9
    disp = np.linalg.norm(sim - v, axis=1)
    img = render.preview_image(v, f, sim, disp, title="dome", panel_px=(400, 300))
    assert img.mode == "RGB" and img.width >= 800 and img.height >= 300
    a = np.asarray(img).astype(int)
    left, right = a[:, 20:400], a[:, 420:800]
    warm = lambda p: ((p[..., 0] - p[..., 2]) > 60).sum()
    # The target is neutral blue-grey, the simulated one in the yellow-red error colours.
    assert warm(left) < 50 and warm(right) > 5000
    assert not_blank(img)


def test_preview_simulated_hotspot_lands_where_the_displacement_is(dome_mesh):
    v, f = dome_mesh
    disp = np.where(v[:, 0] > np.median(v[:, 0]), 4.0, 0.0)  # east half far off
    img = render.preview_image(v, f, v, disp, panel_px=(400, 300), azimuth_deg=0, contour_mm=None)
    a = np.asarray(img).astype(int)
    rows = slice(100, 300)
    west, east = a[rows, 430:600], a[rows, 600:770]
    dark_red = lambda p: ((p[..., 0] > 90) & (p[..., 1] < 60) & (p[..., 2] < 70)).sum()
    assert dark_red(east) > 10 * max(dark_red(west), 1)


def test_preview_shows_the_file_as_given_first_the_sheet_then_the_target(dome_mesh):
    v, f = dome_mesh
    given = v.copy()
    given[:, 2] *= 1.5                     # the file: a dome half again as high
    img = render.preview_image(v, f, v, np.linalg.norm(v - given, axis=1), panel_px=(400, 300),
                               contour_mm=None, given_vertices=given,
                               target_label="planned target (smoothed 6 mm)")
    a = np.asarray(img).astype(int)
    assert img.width >= 1200
    warm = lambda p: ((p[..., 0] - p[..., 2]) > 60).sum()
    ink = lambda p: (p.max(axis=-1) < 250).sum()
    first, second, third = a[:, 20:400], a[:, 420:800], a[:, 820:1200]
    # Neutral file and target, the sheet coloured by its distance from the file.
    assert warm(first) < 50 and warm(third) < 50 and warm(second) > 5000
    # The file stands higher than the target in the same view: more of its panel drawn.
    assert ink(first) > 1.1 * ink(third)


def test_toolpath_image_marks_starts_travel_and_invalid_segments():
    traces = [np.array([[0.0, 0.0], [60.0, 0.0], [60.0, 1.0], [0.0, 1.0]]),
              np.array([[0.0, 20.0], [60.0, 20.0]])]
    sigma = [np.array([0.1, 0.1, 0.2]), np.array([0.6])]
    travel = np.array([[[0.0, 1.0], [0.0, 20.0]]])
    img = render.toolpath_image(traces, sigma, 0.0, 0.343, 0.5, travel=travel, px_per_mm=10)
    assert np.abs(rgb_at(img, (30.0, 20.0)) - INVALID_HIGH).max() <= 3
    expected = colormap([0.1], 0.0, 0.343, "shrink")[0]
    assert np.abs(rgb_at(img, (30.0, 0.0)) - expected).max() <= 3
    assert np.abs(rgb_at(img, (0.0, 0.0)) - render.START_COLOR).max() <= 3
    along = np.array([rgb_at(img, (0.0, y)) for y in np.arange(4.0, 17.0, 0.1)])
    grey = along.max(1) < 235  # anti-aliased thin grey line, or background
    assert 0.2 < grey.mean() < 0.9, "travel is dashed: partly grey, partly background"


def test_heightfield_image_rings_the_removed_peaks():
    hf = shapes.three_islands(diameter_mm=100, pixel_mm=1.0)
    rows = hf.z.shape[0]
    peak = {"x_mm": 50.0, "y_mm": 50.0, "prominence_mm": 4.0}
    img = hfimage.heightfield_image(hf.z, [peak], hf.pixel_mm, title="three islands")
    assert not_blank(img)
    s = img.info["px_per_mm"]
    ox, oy = img.info["origin_px"]
    r_px = 6.0 + 4.0 * np.sqrt(4.0)
    a = np.asarray(img).astype(int)
    ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    px = np.round(ox + s * 50.0 + r_px * np.cos(ang) - 0.5).astype(int)
    py = np.round(oy - s * 50.0 + r_px * np.sin(ang) - 0.5).astype(int)
    ring = a[py, px]
    red = (ring[:, 0] > 150) & (ring[:, 1] < 110) & (ring[:, 2] < 110)
    assert red.mean() > 0.7
    assert rows == hf.z.shape[0]


def test_heightfield_image_maps_where_the_fit_moved_the_surface():
    hf = shapes.dome(diameter_mm=80, height_mm=20, pixel_mm=1.0)
    rows, cols = hf.z.shape
    moved = np.where(np.isfinite(hf.z), 0.0, np.nan)
    moved[:, : cols // 3] = np.where(np.isfinite(hf.z[:, : cols // 3]), 1.0, np.nan)  # west
    plain = np.asarray(hfimage.heightfield_image(hf.z, [], hf.pixel_mm)).astype(int)
    img = hfimage.heightfield_image(hf.z, [], hf.pixel_mm, removed_mm=moved)
    a = np.asarray(img).astype(int)
    s = img.info["px_per_mm"]
    ox, oy = img.info["origin_px"]
    at = lambda x, y: (int(round(oy - s * y)), int(round(ox + s * x)))
    to_tint = lambda c: np.abs(c - np.array(hfimage.REMOVED_COLOR)).sum()
    # Tinted toward the fit's colour where it moved the surface, untouched elsewhere.
    assert to_tint(a[at(15.0, 40.0)]) < to_tint(plain[at(15.0, 40.0)]) - 40
    assert np.array_equal(a[at(60.0, 40.0)], plain[at(60.0, 40.0)])


def test_heightfield_image_on_real_terrain():
    png = SHARED / "data" / "terrain" / "coast_mountains_bc.png"
    if not png.exists():
        pytest.skip("../shared terrain data not available")
    raw = np.asarray(Image.open(png)).astype(np.float64)
    z = raw / 65535.0 * 42.3
    img = hfimage.heightfield_image(z, [], 0.5202, title="coast mountains")
    assert not_blank(img, 500)
    assert max(img.size) >= 900


def test_montage_puts_images_side_by_side_at_one_height():
    a = Image.new("RGB", (200, 100), (255, 0, 0))
    b = Image.new("RGB", (100, 200), (0, 0, 255))
    m = render.montage([a, b], ["red", "blue"], height_px=150)
    arr = np.asarray(m).astype(int)
    assert (np.abs(arr - [255, 0, 0]).max(2) == 0).sum() >= 300 * 150 * 0.9
    assert (np.abs(arr - [0, 0, 255]).max(2) == 0).sum() >= 75 * 150 * 0.9
    assert m.width >= 300 + 75 and m.height > 150
    grid = render.montage([a, b, a], ["r", "b", "r"], height_px=100, columns=2)
    assert grid.height > 2 * 100 and grid.width < 200 + 50 + 200 + 4 * 18


# --- PLY -------------------------------------------------------------------------------------

@pytest.mark.parametrize("channels", [3, 4])
def test_ply_round_trips_through_trimesh(tmp_path, channels):
    rng = np.random.default_rng(3)
    v = rng.uniform(-90, 90, (50, 3))
    f = rng.integers(0, 50, (80, 3))
    c = rng.integers(0, 256, (50, channels)).astype(np.uint8)
    path = tmp_path / "m.ply"
    n = write_ply(path, v, f, c, vertex_scalars={"quality": np.arange(50.0)})
    assert path.stat().st_size == n
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    m = trimesh.load(path, process=False)
    assert np.allclose(m.vertices, v, atol=1e-4)
    assert (m.faces == f).all()
    assert (m.visual.vertex_colors[:, :channels] == c).all()
    raw = m.metadata["_ply_raw"]["vertex"]["data"]
    assert np.allclose(raw["quality"].ravel(), np.arange(50.0))


def test_ply_writes_to_a_file_object_and_without_colours():
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]])
    buf = io.BytesIO()
    write_ply(buf, v, [[0, 1, 2]], double=True)
    buf.seek(0)
    m = trimesh.load(buf, file_type="ply", process=False)
    assert np.array_equal(m.vertices, v) and (m.faces == [[0, 1, 2]]).all()
    with pytest.raises(ValueError):
        write_ply(io.BytesIO(), v, [[0, 1, 3]])


def test_pictures_count_invalid_edges_by_the_reports_criterion():
    from pipeline.printable import SIGMA_TOL
    from pipeline.pictures.render import _split_by_validity
    sigma = np.array([0.343 + SIGMA_TOL / 2, 0.343 + 2 * SIGMA_TOL, -SIGMA_TOL / 2,
                      -2 * SIGMA_TOL, 0.1])
    high, low, ok = _split_by_validity(sigma, 0.0, 0.343)
    # The report's invalid_edge_fraction: sigma outside [s_min - tol, s_max + tol].
    report_invalid = (sigma < -SIGMA_TOL) | (sigma > 0.343 + SIGMA_TOL)
    assert np.array_equal(high | low, report_invalid)
    assert high.tolist() == [False, True, False, False, False]


def test_counts_in_titles_read_as_words():
    from pipeline.pictures.figure import counted
    assert [counted(n, "trace") for n in (0, 1, 2)] == ["0 traces", "1 trace", "2 traces"]


def test_small_parts_are_drawn_no_finer_than_the_paths_need():
    """A 15 mm part's pictures stop at 16 px/mm (a 0.5 mm path 8 px wide) instead of
    stretching it to 1400 px, and its preview panels narrow with it; a 175 mm part keeps
    1400 px on its longest side and 760 px panels."""
    sigma = [np.array([0.1])]
    for size, px_per_mm in ((15.0, render.MAX_PX_PER_MM), (175.0, 1400 / 175.0)):
        img = render.toolpath_image([np.array([[0.0, 0.0], [size, size]])], sigma,
                                    0.0, 0.343, 0.5)
        assert img.info["px_per_mm"] == pytest.approx(px_per_mm)
    widths = []
    for size in (15.0, 175.0):
        v, f = grid_mesh(shapes.dome(diameter_mm=size, height_mm=size / 5,
                                     pixel_mm=size / 40))
        img = render.preview_image(v, f, v, np.zeros(len(v)), contour_mm=None)
        widths.append(img.width)
    assert widths[0] < 0.75 * widths[1]


def test_pictures_are_written_as_png_that_decodes_to_the_same_pixels():
    from hostd.outputs import png_bytes
    rng = np.random.default_rng(3)
    for mode in ("RGB", "RGBA", "L", "P"):
        img = Image.fromarray(rng.integers(0, 256, (37, 53, 4), dtype=np.uint8), "RGBA").convert(mode)
        img.info["dpi"] = (300, 300)
        back = Image.open(io.BytesIO(png_bytes(img)))
        back.load()
        want = img if mode != "P" else img.convert("RGB")
        assert back.format == "PNG" and back.mode == want.mode
        assert np.array_equal(np.asarray(back), np.asarray(want))
        assert back.info["dpi"] == pytest.approx((300, 300), abs=0.01)


def test_drawing_many_segments_holds_little_beside_the_canvas():
    """A 175 mm part's tool paths are a few hundred thousand segments on a 1400 px
    canvas: their spans and the blend are worked out in batches, so the drawing holds
    a few times the canvas, not every drawn pixel's colours at once."""
    import tracemalloc
    from pipeline.pictures.raster import draw_segments
    rng = np.random.default_rng(5)
    p0 = rng.uniform(0, 1400, size=(300_000, 2))
    p1 = p0 + rng.normal(scale=6.0, size=p0.shape)
    canvas = np.full((1400, 1400, 3), 255.0, np.float32)
    tracemalloc.start()
    try:
        draw_segments(canvas, p0, p1, (20, 60, 200), width_px=8.0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 6 * canvas.nbytes          # all at once: 27 times
    assert (canvas < 255).any(axis=2).mean() > 0.9
