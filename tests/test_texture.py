"""Screen-print texture (paper 6.5): opacity, colour, scale, DPI, marks, SVG outline."""

import io
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from PIL import Image

from pipeline.errors import PlanError
from pipeline.geometry import HeightField
from pipeline.pictures.texture import (MM_PER_INCH, boundary_loops, face_opacity, outline_svg,
                              registration_marks, save_texture, texture_image, vertex_colors)

SVG = "{http://www.w3.org/2000/svg}"


def square(size_mm=20.0, h_mm=0.0):
    """Two triangles over a square; vertex 2 raised by ``h_mm`` (face 1 tilts)."""
    s = size_mm
    v = np.array([[0, 0, 0], [s, 0, 0], [s, s, h_mm], [0, s, 0]], float)
    faces = np.array([[0, 1, 3], [1, 2, 3]])
    return v, faces


def grid(n, size_mm, hole=False):
    """Regular (n x n vertices) triangulated square; optionally minus its middle cells."""
    g = np.linspace(0.0, size_mm, n)
    X, Y = np.meshgrid(g, g)
    xy = np.stack([X.ravel(), Y.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    a = (j * n + i).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    if hole:
        c = np.concatenate([(i.ravel()), i.ravel()])
        r = np.concatenate([(j.ravel()), j.ravel()])
        mid = (n - 1) // 2
        keep = ~((abs(c - mid) <= 1) & (abs(r - mid) <= 1))
        faces = faces[keep]
    return xy, faces


def pixels_inside(info, tri_mm, inset=0.8):
    """Integer (row, col) of pixels whose centres lie well inside a layout triangle."""
    s = info["px_per_mm"]
    lo = np.array(info["layout_bbox_mm"][:2])
    ox, oy = info["origin_px"]
    p = np.stack([ox + (tri_mm[:, 0] - lo[0]) * s, oy - (tri_mm[:, 1] - lo[1]) * s], 1)
    c = p.mean(0)
    p = c + inset * (p - c)
    h, w = info["size_px"][1], info["size_px"][0]
    rows, cols = np.mgrid[0:h, 0:w]
    x, y = cols + 0.5, rows + 0.5
    d = lambda a, b: (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
    e = [d(p[0], p[1]), d(p[1], p[2]), d(p[2], p[0])]
    inside = ((e[0] >= 0) & (e[1] >= 0) & (e[2] >= 0)) | ((e[0] <= 0) & (e[1] <= 0) & (e[2] <= 0))
    return np.nonzero(inside)


def test_uniform_colour_opacity_is_target_over_flat_area_per_face():
    v, faces = square(20.0, h_mm=10.0)
    s = 1.25
    xy = v[:, :2] * s
    colors = np.tile([200, 40, 90], (4, 1)).astype(np.uint8)
    img, info = texture_image(v, faces, xy, colors, dpi=200, margin_mm=4, marks=False)
    rgba = np.asarray(img)
    # Face 0 lies in z = 0: a_t/a_f = 1/s^2. Face 1 is tilted: |(v2-v1) x (v3-v1)| / 2.
    a1_t = 0.5 * np.sqrt(800 * 10.0 ** 2 + 160000)
    expect = [1 / s ** 2, a1_t / (200 * s ** 2)]
    assert expect[0] != pytest.approx(expect[1], abs=0.05)
    for f, ratio in enumerate(expect):
        r, c = pixels_inside(info, xy[faces[f]])
        assert len(r) > 500
        alpha = rgba[r, c, 3].astype(int)
        assert np.all(np.abs(alpha - 255 * ratio) <= 1), (f, alpha.min(), alpha.max(), ratio)
        assert np.all(rgba[r, c, :3] == [200, 40, 90])
    assert info["opacity"]["min"] == pytest.approx(expect[0])
    assert info["opacity"]["max"] == pytest.approx(expect[1])
    # Background stays fully transparent.
    assert rgba[0, 0, 3] == 0 and rgba[-1, -1, 3] == 0


def test_opacity_clips_faces_that_would_grow():
    v, faces = square(20.0, h_mm=10.0)
    op, a_t, a_f = face_opacity(v, faces, v[:, :2] * 0.5)
    assert np.all(op == 1.0) and np.all(a_t > a_f)
    op, _, _ = face_opacity(v, faces, v[:, :2] * 2.0)
    assert op[0] == pytest.approx(0.25)


def test_colour_interpolates_barycentrically():
    v = np.array([[0, 0, 0], [40, 0, 0], [0, 40, 0]], float)
    faces = np.array([[0, 1, 2]])
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)
    img, info = texture_image(v, faces, v[:, :2], colors, dpi=150, margin_mm=0, marks=False)
    rgba = np.asarray(img).astype(int)
    s = info["px_per_mm"]
    h = info["size_px"][1]

    def at(x_mm, y_mm):
        return rgba[int(h - y_mm * s), int(x_mm * s)]

    centroid = at(40 / 3, 40 / 3)
    assert np.all(np.abs(centroid[:3] - 85) <= 3), centroid
    # Barycentric (0.6, 0.3, 0.1): x = 0.3 * 40, y = 0.1 * 40.
    assert np.all(np.abs(at(12.0, 4.0)[:3] - [153, 76.5, 25.5]) <= 3)
    assert at(12.0, 4.0)[3] == 255


def test_dpi_is_stored_in_the_png():
    v, faces = square(20.0)
    for dpi in (150, 300):
        img, info = texture_image(v, faces, v[:, :2], np.full((4, 3), 90, np.uint8), dpi=dpi)
        assert info["dpi"] == dpi
        buf = io.BytesIO()
        save_texture(img, buf)
        back = Image.open(io.BytesIO(buf.getvalue()))
        assert back.info["dpi"] == pytest.approx((dpi, dpi), rel=1e-3)
        assert back.size == tuple(info["size_px"]) and back.mode == "RGBA"


def test_one_to_one_scale_50mm_square():
    v, faces = square(50.0)
    for dpi in (300, 200):
        img, info = texture_image(v, faces, v[:, :2], np.full((4, 3), 50, np.uint8), dpi=dpi,
                                  margin_mm=0, marks=False)
        px = 50.0 / MM_PER_INCH * dpi
        a = np.asarray(img)[..., 3]
        row = a[a.shape[0] // 2]
        col = a[:, a.shape[1] // 2]
        assert abs(np.count_nonzero(row) - px) <= 1
        assert abs(np.count_nonzero(col) - px) <= 1
        assert info["size_px"] == [int(np.ceil(px))] * 2
        assert info["size_mm"][0] == pytest.approx(50.0, abs=25.4 / dpi)


def test_marks_at_reported_pixels():
    v, faces = square(30.0)
    xy = v[:, :2] * 1.2 + [7.0, -3.0]
    m = 12.0
    img, info = texture_image(v, faces, xy, np.full((4, 3), 200, np.uint8), dpi=300, margin_mm=m)
    rgba = np.asarray(img).astype(int)
    marks = info["marks"]
    assert [k["name"] for k in marks] == ["lower_left", "lower_right", "upper_right", "upper_left"]
    w = h = 36.0
    expect_bbox = [[-m / 2, -m / 2], [w + m / 2, -m / 2], [w + m / 2, h + m / 2], [-m / 2, h + m / 2]]
    assert np.allclose([k["bbox_mm"] for k in marks], expect_bbox)
    assert np.allclose(registration_marks(xy, m), [k["layout_mm"] for k in marks])
    s = info["px_per_mm"]
    for k in marks:
        x, y = k["px"]
        # The page's top-left corner is the bbox corner minus the margin.
        assert x == pytest.approx((k["bbox_mm"][0] + m) * s)
        assert y == pytest.approx((h + m - k["bbox_mm"][1]) * s)
        centre = rgba[int(y), int(x)]
        assert centre[3] == 255 and np.all(centre[:3] == 0)
        r = k["radius_mm"] * s / np.sqrt(2)
        for sx, sy in [(1, 1), (-1, 1), (1, -1), (-1, -1)]:
            assert rgba[int(y + sy * r), int(x + sx * r), 3] > 200  # on the circle
            assert rgba[int(y + sy * r / 2), int(x + sx * r / 2), 3] == 0  # inside, off the cross
    bare, _ = texture_image(v, faces, xy, np.full((4, 3), 200, np.uint8), dpi=300, margin_mm=m,
                            marks=False)
    x, y = marks[0]["px"]
    assert np.asarray(bare)[int(y), int(x), 3] == 0


def _path_points(d):
    nums = np.array([float(t) for t in re.findall(r"-?\d+(?:\.\d+)?", d)])
    return nums.reshape(-1, 2)


def test_outline_svg_parses_with_extent_in_mm_and_flipped_y():
    xy, faces = grid(9, 50.0)
    xy = xy + [100.0, 20.0]
    m = 10.0
    _, info = texture_image(np.c_[xy, np.zeros(len(xy))], faces, xy,
                            np.full((len(xy), 3), 10, np.uint8), dpi=300, margin_mm=m)
    text = outline_svg(xy, faces, info["marks"], m)
    root = ET.fromstring(text.encode())
    assert root.tag == SVG + "svg"
    assert root.get("width") == "70mm" and root.get("height") == "70mm"
    assert [float(t) for t in root.get("viewBox").split()] == [0, 0, 70, 70]
    outline = root.find(f".//{SVG}path[@id='outline']")
    pts = _path_points(outline.get("d"))
    assert np.allclose(pts.min(0), [m, m]) and np.allclose(pts.max(0), [m + 50, m + 50])
    assert len(pts) == 32  # the 8 x 4 boundary vertices of a 9 x 9 grid
    # Same page as the PNG: mark centres in mm times px/mm are the reported pixels.
    circles = root.findall(f".//{SVG}circle")
    assert len(circles) == 4
    got = np.array([[float(c.get("cx")), float(c.get("cy"))] for c in circles])
    assert np.allclose(got * info["px_per_mm"], [k["px"] for k in info["marks"]], atol=0.05)
    # y flips like the image: the layout's highest point is nearest the page top.
    tri = np.array([[0.0, 0.0], [50.0, 0.0], [0.0, 30.0]])
    root = ET.fromstring(outline_svg(tri, np.array([[0, 1, 2]]), False, m))
    pts = _path_points(root.find(f".//{SVG}path[@id='outline']").get("d"))
    assert sorted(map(tuple, np.round(pts, 6))) == [(m, m), (m, m + 30), (m + 50, m + 30)]


def test_outline_svg_matches_png_page_with_dpi():
    xy, faces = grid(5, 33.3)
    _, info = texture_image(np.c_[xy, np.zeros(len(xy))], faces, xy,
                            np.zeros((len(xy), 3), np.uint8), dpi=300, margin_mm=5)
    root = ET.fromstring(outline_svg(xy, faces, True, 5, dpi=300))
    assert float(root.get("width")[:-2]) == pytest.approx(info["size_mm"][0], abs=1e-3)


def test_boundary_loops_outer_ccw_hole_cw():
    xy, faces = grid(9, 8.0, hole=True)
    loops = boundary_loops(faces)
    assert len(loops) == 2
    area = lambda p: 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    assert area(xy[loops[0]]) == pytest.approx(64.0)
    assert area(xy[loops[1]]) == pytest.approx(-9.0)
    root = ET.fromstring(outline_svg(xy, faces, False, 2.0))
    assert root.find(f".//{SVG}path[@id='outline']").get("d").count("M") == 2
    assert root.findall(f".//{SVG}circle") == []


def test_vertex_colors_bilinear_north_up():
    color = np.zeros((3, 4, 3), np.uint8)
    color[0, :, 0] = 200  # north row red
    color[:, :, 2] = np.array([0, 40, 80, 120], np.uint8)  # blue grows east
    hf = HeightField(np.zeros((3, 4)), 2.0, color=color)
    pts = np.array([[0.0, 4.0, 1.0], [3.0, 3.0, 0.0], [6.0, 0.0, 0.0]])
    c = vertex_colors(hf, pts).astype(int)
    assert c[0].tolist() == [200, 0, 0]
    assert c[1].tolist() == [100, 0, 60]  # half-way in x and y
    assert c[2].tolist() == [0, 0, 120]
    with pytest.raises(PlanError) as e:
        vertex_colors(HeightField(np.zeros((3, 4)), 2.0), pts)
    assert e.value.code == "texture.no_color"


def test_bad_input_raises_clear_error():
    v, faces = square(20.0)
    with pytest.raises(PlanError) as e:
        texture_image(v, faces, v[:3, :2], np.zeros((4, 3), np.uint8))
    assert e.value.code == "texture.bad_input"
    with pytest.raises(PlanError) as e:
        texture_image(v * 1000, faces, v[:, :2] * 1000, np.zeros((4, 3), np.uint8), dpi=300)
    assert e.value.code == "texture.too_large"


def test_colour_pass_in_row_bands_matches_one_pass(monkeypatch):
    from pipeline.pictures import texture
    xy, faces = grid(41, 60.0)
    v = np.c_[xy, 3.0 * np.sin(xy[:, :1] / 7.0)]
    colors = np.random.default_rng(1).integers(0, 256, (len(xy), 3)).astype(np.uint8)
    one, _ = texture_image(v, faces, xy, colors, dpi=200, margin_mm=0, marks=False)
    monkeypatch.setattr(texture, "_BAND_PX", 5000)  # ~10 rows per band
    banded, _ = texture_image(v, faces, xy, colors, dpi=200, margin_mm=0, marks=False)
    a = np.asarray(banded)
    assert np.count_nonzero(a[..., 3]) / a[..., 3].size > 0.995
    # Shifting the rows changes float rounding only: at most 1 level off.
    assert np.abs(a.astype(int) - np.asarray(one)).max() <= 1
