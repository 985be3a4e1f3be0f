"""Input reading: formats, scale from sidecars, colour, and every refused input's code."""

import pickle
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from pipeline.input import heightfield as H
from pipeline.input import sidecar as S
from pipeline.errors import InvalidHeightField, InvalidSidecar
from pipeline.profiles.profile import load_profile

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
TERRAIN = SHARED / "data" / "terrain"


def _bump(rows=40, cols=60):
    """A smooth bump in 0..1, max 1 at the centre."""
    y, x = np.mgrid[0:rows, 0:cols]
    return np.exp(-(((x - cols / 2) / (cols / 4)) ** 2 + ((y - rows / 2) / (rows / 4)) ** 2))


def _png16(path, a):
    Image.fromarray(np.round(a * 65535).astype(np.uint16)).save(path)
    return path


def _code(e):
    return e.value.code


# ---------------------------------------------------------------- reading and scale

def test_png16_with_sidecar_size_and_height(tmp_path):
    a = _bump()
    path = _png16(tmp_path / "hill.png", a)
    (tmp_path / "hill.yaml").write_text("size_mm: 118\nheight_mm: 20\nmax_fill_mm: 3\ncopies: 2\n")
    hf, sc = H.load(path)
    assert hf.z.shape == (40, 60)
    # Longest footprint side: 59 pixel steps span 118 mm.
    assert hf.pixel_mm == pytest.approx(2.0)
    assert np.nanmax(hf.z) == pytest.approx(20.0)
    assert np.nanmin(hf.z) == pytest.approx(0.0)
    assert sc.max_fill_mm == 3.0 and sc.copies == 2 and sc.source.endswith("hill.yaml")
    assert hf.source == str(path)


def test_png8_without_sidecar_uses_profile_defaults(tmp_path):
    path = tmp_path / "b.png"
    Image.fromarray(np.round(_bump() * 255).astype(np.uint8)).save(path)
    p = load_profile("generic-0.5mm")
    hf, sc = H.load(path, profile=p)
    assert sc.source is None
    assert hf.pixel_mm == pytest.approx(p.defaults.size_mm / 59)
    assert np.nanmax(hf.z) == pytest.approx(p.defaults.height_mm)


def test_height_scale_is_per_input_unit(tmp_path):
    a = np.zeros((20, 20), np.uint8)
    a[5:15, 5:15] = 100
    path = tmp_path / "s.png"
    Image.fromarray(a).save(path)
    (tmp_path / "s.yaml").write_text("pixel_mm: 0.5\nheight_scale: 0.1\n")
    hf, _ = H.load(path)
    assert np.nanmax(hf.z) == pytest.approx(10.0)
    assert hf.pixel_mm == 0.5


def test_alpha_zero_is_outside(tmp_path):
    a = np.round(_bump() * 255).astype(np.uint8)
    alpha = np.full_like(a, 255)
    alpha[:, :10] = 0
    Image.fromarray(np.dstack([a, alpha]), "LA").save(tmp_path / "la.png")
    hf, _ = H.load(tmp_path / "la.png")
    assert np.isnan(hf.z[:, :10]).all() and np.isfinite(hf.z[:, 10:]).all()
    # The footprint (not the image) sets the scale: 49 steps for the default 150 mm.
    assert hf.pixel_mm == pytest.approx(150.0 / 49)


def test_grey_rgb_accepted_colour_rgb_refused(tmp_path):
    g = np.round(_bump() * 255).astype(np.uint8)
    Image.fromarray(np.dstack([g, g, g])).save(tmp_path / "grey.png")
    hf, _ = H.load(tmp_path / "grey.png")
    assert np.nanmax(hf.z) == pytest.approx(30.0)
    Image.fromarray(np.dstack([g, g // 2, g])).save(tmp_path / "col.png")
    with pytest.raises(InvalidHeightField) as e:
        H.load(tmp_path / "col.png")
    assert _code(e) == "heightfield.not_2d"


def test_an_image_without_a_height_gets_a_relief_in_proportion_to_its_size(tmp_path):
    g = np.round(_bump() * 255).astype(np.uint8)            # 40 x 60 samples
    Image.fromarray(g).save(tmp_path / "t.png")
    (tmp_path / "t.yaml").write_text("size_mm: 60\n")
    hf, _ = H.load(tmp_path / "t.png")
    # The default 30 mm belongs to the default 150 mm: at 60 mm, 12 mm (same slopes).
    assert np.nanmax(hf.z) == pytest.approx(12.0)
    (tmp_path / "t.yaml").write_text("size_mm: 60\nheight_mm: 25\n")
    hf, _ = H.load(tmp_path / "t.png")
    assert np.nanmax(hf.z) == pytest.approx(25.0)


def test_tiff16_and_float_tiff(tmp_path):
    a = _bump()
    Image.fromarray(np.round(a * 65535).astype(np.uint16)).save(tmp_path / "a.tif")
    (tmp_path / "a.yaml").write_text("pixel_mm: 1.0\nheight_mm: 12\n")
    hf, _ = H.load(tmp_path / "a.tif")
    assert np.nanmax(hf.z) == pytest.approx(12.0)
    Image.fromarray((a * 7).astype(np.float32)).save(tmp_path / "f.tiff")
    (tmp_path / "f.yaml").write_text("pixel_mm: 1.0\nheight_scale: 1.0\n")
    hf, _ = H.load(tmp_path / "f.tiff")
    assert np.nanmax(hf.z) == pytest.approx(7.0 * (a.max() - a.min()), rel=1e-5)


def test_npy_is_millimetres_with_nan_outside(tmp_path):
    z = 5.0 + 10 * _bump()
    z[:3] = np.nan
    np.save(tmp_path / "z.npy", z)
    (tmp_path / "z.yaml").write_text("pixel_mm: 0.25\n")
    hf, _ = H.load(tmp_path / "z.npy")
    # Shifted so the lowest footprint point is 0; units untouched.
    np.testing.assert_allclose(hf.z, z - np.nanmin(z))
    assert hf.pixel_mm == 0.25


@pytest.mark.parametrize("keys", [("anything",), ("z", "other"), ("height", "x")])
def test_npz_key_choice(tmp_path, keys):
    z = 10 * _bump()
    arrays = {k: (z if k in ("anything", "z", "height") else np.zeros(3)) for k in keys}
    np.savez(tmp_path / "a.npz", **arrays)
    hf, _ = H.load(tmp_path / "a.npz")
    np.testing.assert_allclose(hf.z, z - z.min())


def test_npz_ambiguous(tmp_path):
    np.savez(tmp_path / "a.npz", a=_bump(), b=_bump())
    with pytest.raises(InvalidHeightField) as e:
        H.load(tmp_path / "a.npz")
    assert _code(e) == "heightfield.npz_key"


def test_color_png_resampled(tmp_path):
    _png16(tmp_path / "c.png", _bump())
    rgb = np.zeros((80, 120, 3), np.uint8)
    rgb[..., 0] = 200
    Image.fromarray(rgb).save(tmp_path / "c.color.png")
    hf, _ = H.load(tmp_path / "c.png")
    assert hf.color.shape == (40, 60, 3) and hf.color.dtype == np.uint8
    assert (hf.color[..., 0] == 200).all() and (hf.color[..., 1] == 0).all()
    Image.fromarray(np.zeros((60, 60, 3), np.uint8)).save(tmp_path / "c.color.png")
    with pytest.raises(InvalidHeightField) as e:
        H.load(tmp_path / "c.png")
    assert _code(e) == "heightfield.color_mismatch"


def _top_half(mesh):
    """The upper half of a closed mesh, open at z = 0: a surface, not a solid (a closed
    solid is refused, :mod:`tests.test_mesh_up`)."""
    return mesh.slice_plane([0, 0, 0], [0, 0, 1])


@pytest.mark.parametrize("ext", ["stl", "ply", "obj", "glb"])
def test_mesh_top_surface(tmp_path, ext):
    sphere = _top_half(trimesh.creation.icosphere(subdivisions=4, radius=20.0))
    path = tmp_path / ("ball." + ext)
    sphere.export(path)
    (tmp_path / "ball.yaml").write_text("pixel_mm: 0.5\n")
    hf, _ = H.load(path)
    # The top hemisphere seen from above: apex 20 mm over the rim (the lowest top sample).
    assert np.nanmax(hf.z) == pytest.approx(20.0, abs=0.3)
    area = np.isfinite(hf.z).sum() * 0.25
    assert area == pytest.approx(np.pi * 20 ** 2, rel=0.03)
    # Centre sample is the apex, near-rim samples are low.
    r, c = np.array(hf.z.shape) // 2
    assert hf.z[r, c] == pytest.approx(np.nanmax(hf.z), abs=0.1)


def test_mesh_solid_block_keeps_top_only(tmp_path):
    # A terrain-like solid: a wavy top over a flat bottom and walls.
    g = np.linspace(0, 30, 31)
    x, y = np.meshgrid(g, g)
    top = 5 + 3 * np.sin(x / 5) * np.cos(y / 7)
    verts = np.column_stack([x.ravel(), y.ravel(), top.ravel()])
    n = 31
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    bottom = verts.copy()
    bottom[:, 2] = 0.0
    m = trimesh.Trimesh(np.vstack([verts, bottom]), np.vstack([faces, faces[:, ::-1] + n * n]))
    m.export(tmp_path / "block.stl")
    (tmp_path / "block.yaml").write_text("pixel_mm: 1.0\n")
    hf, _ = H.load(tmp_path / "block.stl")
    assert hf.z.shape == (31, 31)
    # Row 0 is north (max y): sample (row, col) is grid point (x=col, y=30-row).
    np.testing.assert_allclose(hf.z, (top - top.min())[::-1], atol=1e-5)  # STL is float32


def test_mesh_vertex_colours(tmp_path):
    m = _top_half(trimesh.creation.icosphere(subdivisions=3, radius=10.0))
    colors = np.zeros((len(m.vertices), 4), np.uint8)
    colors[:, 3] = 255
    colors[m.vertices[:, 0] > 0, 0] = 255  # east half red
    m.visual.vertex_colors = colors
    m.export(tmp_path / "c.ply")
    (tmp_path / "c.yaml").write_text("pixel_mm: 0.5\n")
    hf, _ = H.load(tmp_path / "c.ply")
    assert hf.color is not None
    inside = np.isfinite(hf.z)
    cols = np.nonzero(inside.any(axis=0))[0]
    assert hf.color[inside[:, cols[-1]], cols[-1], 0].min() > 200
    assert hf.color[inside[:, cols[0]], cols[0], 0].max() < 50


def test_mesh_size_mm_scales_uniformly(tmp_path):
    _top_half(trimesh.creation.icosphere(subdivisions=3, radius=1.0)).export(tmp_path / "u.stl")
    (tmp_path / "u.yaml").write_text("size_mm: 40\n")
    hf, _ = H.load(tmp_path / "u.stl")
    assert np.nanmax(hf.z) == pytest.approx(20.0, abs=0.3)
    assert hf.pixel_mm == H.MESH_PIXEL_MM


@pytest.mark.skipif(not TERRAIN.is_dir(), reason="../shared not present")
@pytest.mark.parametrize("name,pixel_mm,height_mm", [("vancouver_island_south", 0.5650, 34.7),
                                                     ("coast_mountains_bc", 0.5202, 42.3)])
def test_real_terrain_matches_its_readme(name, pixel_mm, height_mm):
    hf, sc = H.load(TERRAIN / (name + ".png"), load_profile("generic-0.5mm"))
    assert hf.z.shape == (200, 200)
    assert hf.pixel_mm == pytest.approx(pixel_mm, abs=1e-4)
    assert np.nanmax(hf.z) == pytest.approx(height_mm)
    assert sc.max_fill_mm >= 5.0


# ---------------------------------------------------------------- refused inputs

def _png_bytes(a):
    import io
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, "PNG")
    return buf.getvalue()


def _patched_ihdr(width, height):
    """A valid small PNG whose header then claims width x height pixels (CRC fixed)."""
    data = bytearray(_png_bytes(np.zeros((20, 20), np.uint8)))
    assert data[12:16] == b"IHDR"
    data[16:24] = struct.pack(">II", width, height)
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    return bytes(data)


def _expect(path, code, **kw):
    with pytest.raises(InvalidHeightField) as e:
        H.load(path, **kw)
    assert _code(e) == code, e.value.text()
    assert e.value.file == str(path) and e.value.fix
    return e.value


def test_missing_file(tmp_path):
    _expect(tmp_path / "nope.png", "heightfield.not_found")


def test_empty_file(tmp_path):
    (tmp_path / "e.png").write_bytes(b"")
    _expect(tmp_path / "e.png", "heightfield.empty")


def test_unknown_extension(tmp_path):
    (tmp_path / "z.bmp").write_bytes(b"BM" + bytes(100))
    _expect(tmp_path / "z.bmp", "heightfield.unsupported_type")


@pytest.mark.parametrize("name", ["t.png", "t.npy", "t.npz", "t.tif", "t.glb", "t.ply", "t.stl"])
def test_text_with_binary_extension(tmp_path, name):
    (tmp_path / name).write_text("this is not a height field\n" * 10)
    _expect(tmp_path / name, "heightfield.content_mismatch")


def test_truncated_png(tmp_path):
    rng = np.random.default_rng(0)
    data = _png_bytes((rng.random((120, 120)) * 65535).astype(np.uint16))
    (tmp_path / "t.png").write_bytes(data[: len(data) // 2])
    _expect(tmp_path / "t.png", "heightfield.truncated")


def test_png_header_declaring_huge_size_is_refused_before_decoding(tmp_path):
    # Over our limit but under Pillow's own bomb limit: our header check must catch it.
    (tmp_path / "big.png").write_bytes(_patched_ihdr(6000, 6000))
    err = _expect(tmp_path / "big.png", "heightfield.too_many_pixels")
    assert err.details["pixels"] == 36_000_000
    assert "raise validate.max_pixels" in err.fix          # a large map: the limit may move
    # Far over Pillow's limit (it raises DecompressionBombError at open): a bomb, whose fix
    # is never to raise the limit.
    (tmp_path / "bomb.png").write_bytes(_patched_ihdr(100_000, 100_000))
    bomb = _expect(tmp_path / "bomb.png", "heightfield.too_many_pixels")
    assert "max_pixels" not in bomb.fix and "export it again" in bomb.fix


def test_max_pixels_argument(tmp_path):
    _png16(tmp_path / "a.png", _bump())
    _expect(tmp_path / "a.png", "heightfield.too_many_pixels", max_pixels=1000)
    np.save(tmp_path / "a.npy", _bump())
    _expect(tmp_path / "a.npy", "heightfield.too_many_pixels", max_pixels=1000)


def test_huge_npy_header_refused_before_reading(tmp_path):
    # Header claims 100k x 100k float64 (80 GB) with no data: must fail on the header.
    path = tmp_path / "h.npy"
    with open(path, "wb") as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": "<f8", "fortran_order": False, "shape": (100_000, 100_000)})
        f.write(b"\0" * 64)
    _expect(path, "heightfield.too_many_pixels")


def test_pickled_npy(tmp_path):
    path = tmp_path / "p.npy"
    np.save(path, np.array([[{"evil": 1}, None]], dtype=object), allow_pickle=True)
    _expect(path, "heightfield.pickled")


def test_pickle_file_named_npy(tmp_path):
    path = tmp_path / "raw.npy"
    path.write_bytes(pickle.dumps(np.zeros((20, 20))))
    _expect(path, "heightfield.content_mismatch")


def test_truncated_npy(tmp_path):
    path = tmp_path / "t.npy"
    np.save(path, _bump())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 500])
    _expect(path, "heightfield.truncated")


def test_truncated_npz(tmp_path):
    path = tmp_path / "t.npz"
    np.savez_compressed(path, z=np.random.default_rng(1).random((50, 50)))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _expect(path, "heightfield.truncated")


def test_truncated_binary_stl(tmp_path):
    path = tmp_path / "t.stl"
    trimesh.creation.icosphere(subdivisions=3).export(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 1000])
    _expect(path, "heightfield.truncated")


@pytest.mark.parametrize("shape", [(10, 10, 3), (100,), ()])
def test_not_2d_array(tmp_path, shape):
    np.save(tmp_path / "a.npy", np.ones(shape))
    _expect(tmp_path / "a.npy", "heightfield.not_2d")


def test_non_numeric_dtype(tmp_path):
    np.save(tmp_path / "a.npy", np.full((20, 20), "x"))
    _expect(tmp_path / "a.npy", "heightfield.bad_dtype")


def test_flat_field(tmp_path):
    np.save(tmp_path / "f.npy", np.full((30, 30), 4.0))
    _expect(tmp_path / "f.npy", "heightfield.flat")
    Image.fromarray(np.full((30, 30), 128, np.uint8)).save(tmp_path / "f.png")
    _expect(tmp_path / "f.png", "heightfield.flat")


def test_inf_inside_footprint(tmp_path):
    z = _bump()
    z[10, 12] = np.inf
    np.save(tmp_path / "i.npy", z)
    err = _expect(tmp_path / "i.npy", "heightfield.non_finite")
    assert "row 10, col 12" in err.where


def test_all_nan_has_no_footprint(tmp_path):
    np.save(tmp_path / "n.npy", np.full((30, 30), np.nan))
    _expect(tmp_path / "n.npy", "heightfield.no_footprint")
    a = np.zeros((30, 30, 2), np.uint8)
    a[..., 0] = np.arange(30)
    Image.fromarray(a, "LA").save(tmp_path / "n.png")
    _expect(tmp_path / "n.png", "heightfield.no_footprint")


def test_too_small(tmp_path):
    np.save(tmp_path / "s.npy", _bump(10, 40))
    _expect(tmp_path / "s.npy", "heightfield.too_small")
    # A big image whose footprint is tiny is just as unmeshable.
    z = np.full((100, 100), np.nan)
    z[40:45, 40:80] = _bump(5, 40)
    np.save(tmp_path / "t.npy", z)
    _expect(tmp_path / "t.npy", "heightfield.too_small")


# ---------------------------------------------------------------- sidecars

@pytest.mark.parametrize("text,code,key", [
    ("size_mm: 100\ncolour: red\n", "sidecar.unknown_key", "colour"),
    ("size_mm: big\n", "sidecar.type", "size_mm"),
    ("copies: 1.5\n", "sidecar.type", "copies"),
    ("copies: 0\n", "sidecar.value", "copies"),
    ("max_fill_mm: -1\n", "sidecar.value", "max_fill_mm"),
    ("profile: 3\n", "sidecar.type", "profile"),
    ("size_mm: 100\npixel_mm: 0.5\n", "sidecar.conflict", "pixel_mm"),
    ("height_mm: 10\nheight_scale: 0.5\n", "sidecar.conflict", "height_scale"),
    ("size_mm: [1\n", "sidecar.yaml", None),
    ("- 1\n- 2\n", "sidecar.type", None),
])
def test_bad_sidecar(tmp_path, text, code, key):
    _png16(tmp_path / "a.png", _bump())
    (tmp_path / "a.yaml").write_text(text)
    with pytest.raises(InvalidSidecar) as e:
        H.load(tmp_path / "a.png")
    assert _code(e) == code
    assert e.value.file == str(tmp_path / "a.yaml")
    if key:
        assert e.value.where == key


def test_sidecar_all_keys_and_settings(tmp_path):
    (tmp_path / "a.yaml").write_text(
        "pixel_mm: 0.5\nheight_scale: 0.01\nprofile: prusa-mk3s-0.4mm\nmax_fill_mm: 4\n"
        "min_prominence_mm: 1.5\ncopies: 3\npriority: -2\n")
    sc = S.load_sidecar(tmp_path / "a.yaml")
    assert (sc.pixel_mm, sc.height_scale, sc.profile, sc.copies, sc.priority) == \
        (0.5, 0.01, "prusa-mk3s-0.4mm", 3, -2)
    p = load_profile("generic-0.5mm")
    s = S.settings(sc, p)
    assert s == {"max_fill_mm": 4.0, "min_prominence_mm": 1.5, "smooth_mm": p.mesh.smooth_mm}
    assert S.settings(S.Sidecar(), p)["max_fill_mm"] == p.validate.max_fill_mm
    assert S.load_sidecar(tmp_path / "missing.yaml") == S.Sidecar()


def test_coarsen_averages_whole_blocks_keeps_the_outline_and_the_colour():
    from pipeline.geometry import HeightField
    z = np.arange(100, dtype=float).reshape(10, 10)
    z[:3, :3] = np.nan                 # 9 of block (0, 0)'s 25 samples outside: it stays in
    z[5:, 5:] = np.nan                 # block (1, 1) wholly outside
    color = np.zeros((10, 10, 3), np.uint8)
    color[:, 5:] = [200, 100, 50]
    hf = HeightField(z, 0.05, color=color, source="t")
    out, k = H.coarsen(hf, 0.25)
    assert k == 5 and out.pixel_mm == pytest.approx(0.25) and out.z.shape == (2, 2)
    block = z[:5, :5]
    expect = np.array([[np.nanmean(block), z[:5, 5:].mean()], [z[5:, :5].mean(), np.nan]])
    expect -= np.nanmin(expect)
    np.testing.assert_allclose(out.z, expect)
    assert out.color[0, 1].tolist() == [200, 100, 50] and out.color[1, 0].tolist() == [0, 0, 0]
    z2 = z.copy()
    z2[:4, :4] = np.nan                # 16 of 25 outside: the block leaves the footprint
    assert np.isnan(H.coarsen(HeightField(z2, 0.05), 0.25)[0].z[0, 0])
    # Already coarse enough, or switched off: untouched.
    assert H.coarsen(hf, 0.09)[1] == 1 and H.coarsen(hf, 0.0)[0] is hf


def test_a_fine_height_map_is_planned_on_working_samples(tmp_path):
    """A height map with 0.05 mm pixels (1.4 megapixels for a 60 mm dome) is planned
    on 0.25 mm samples; the report keeps the input's shape and pixel and says what
    was worked on, and the result matches the dome given at 0.25 mm directly."""
    from pipeline.input import shapes
    from pipeline.plan import plan_file
    from pipeline.profiles.profile import load_profile
    prof = load_profile("generic-0.5mm")
    fine = shapes.dome(diameter_mm=60.0, height_mm=12.0, pixel_mm=0.05)
    np.save(tmp_path / "fine.npy", fine.z.astype(np.float32))
    (tmp_path / "fine.yaml").write_text("pixel_mm: 0.05\n")
    coarse = shapes.dome(diameter_mm=60.0, height_mm=12.0, pixel_mm=0.25)
    np.save(tmp_path / "coarse.npy", coarse.z.astype(np.float32))
    (tmp_path / "coarse.yaml").write_text("pixel_mm: 0.25\n")
    a = plan_file(tmp_path / "fine.npy", prof).report
    b = plan_file(tmp_path / "coarse.npy", prof).report
    assert a["heightfield"]["shape"] == list(fine.z.shape)
    assert a["heightfield"]["pixel_mm"] == pytest.approx(0.05)
    assert a["heightfield"]["working_pixel_mm"] == pytest.approx(0.25)
    assert a["heightfield"]["working_shape"] == [-(-s // 5) for s in fine.z.shape]
    assert b["heightfield"]["working_shape"] == b["heightfield"]["shape"]
    for r in (a, b):
        assert r["flatten"]["invalid_edge_fraction"] < 0.01
    assert a["mesh"]["triangles"] == pytest.approx(b["mesh"]["triangles"], rel=0.05)
    assert a["heightfield"]["max_height_mm"] == pytest.approx(12.0, abs=0.1)
