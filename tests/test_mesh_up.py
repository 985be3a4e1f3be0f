"""Meshes read whichever way up they were exported, or refused when no side is up."""

import numpy as np
import pytest
import trimesh

from pipeline.errors import InvalidHeightField, InvalidSidecar
from pipeline.input import heightfield as H
from pipeline.input import meshread
from pipeline.input.validate import validate


def hemisphere(radius, rings=24, segments=64, rim_deg=90.0):
    """An open hemisphere shell (a cap down to ``rim_deg`` from the apex), apex on +Z,
    normals outward: (vertices, faces)."""
    theta = np.linspace(0, np.radians(rim_deg), rings + 1)[1:]   # from the apex to the rim
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.column_stack([(np.sin(t) * np.cos(p)).ravel(), (np.sin(t) * np.sin(p)).ravel(),
                            np.cos(t).ravel()]) * radius
    verts = np.vstack([[0.0, 0.0, radius], ring])
    idx = 1 + np.arange(rings * segments).reshape(rings, segments)
    nxt = np.roll(idx, -1, axis=1)
    cap = np.column_stack([np.zeros(segments, int), idx[0], nxt[0]])
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    quads = np.concatenate([np.column_stack([a.ravel(), c.ravel(), d.ravel()]),
                            np.column_stack([a.ravel(), d.ravel(), b.ravel()])])
    return verts, np.vstack([cap, quads])


def _y_up(verts):
    """A Z-up model as an exporter with Y up writes it (Blender's OBJ: y = z, z = -y)."""
    x, y, z = verts.T
    return np.column_stack([x, z, -y])


def _write_obj(path, verts, faces):
    trimesh.Trimesh(verts, faces, process=False).export(path)


@pytest.mark.parametrize("turn", ["z", "y"])
def test_hemisphere_read_as_a_dome_either_way_up(tmp_path, turn):
    verts, faces = hemisphere(75.0)
    if turn == "y":
        verts = _y_up(verts)
    path = tmp_path / "dome.obj"
    _write_obj(path, verts, faces)
    (tmp_path / "dome.yaml").write_text("size_mm: 150\n")
    hf, _ = H.load(path)
    assert hf.up["up"] == "+" + turn and hf.up["chosen"] == "auto"
    assert hf.up["facing_away"] < 0.01
    inside = np.isfinite(hf.z)
    rows, cols = np.nonzero(inside)
    # A round footprint 150 mm across: as wide as deep, and the disc's area.
    width = (cols.max() - cols.min()) * hf.pixel_mm
    depth = (rows.max() - rows.min()) * hf.pixel_mm
    assert width == pytest.approx(150.0, rel=0.01) and depth == pytest.approx(150.0, rel=0.01)
    assert inside.sum() * hf.pixel_mm ** 2 == pytest.approx(np.pi * 75 ** 2, rel=0.02)
    _, rep = validate(hf, 1.0)
    assert rep["max_height_mm"] == pytest.approx(75.0, rel=0.02)


def test_y_up_hemisphere_read_with_z_would_be_a_wall():
    """What the choice prevents: seen from +Z, a Y-up dome stands on its side."""
    verts, faces = hemisphere(75.0)
    shares = meshread.facing_away(_y_up(verts), faces)
    assert shares["y"] < 0.01 and shares["z"] > 0.3 and shares["-y"] > 0.99


def test_sidecar_up_overrides(tmp_path):
    verts, faces = hemisphere(20.0)
    path = tmp_path / "d.obj"
    _write_obj(path, _y_up(verts), faces)
    (tmp_path / "d.yaml").write_text("up: z\n")
    hf, _ = H.load(path)
    assert hf.up == dict(hf.up, up="+z", chosen="sidecar")
    # Seen from +Z the dome is half a disc of its side: 40 mm across one way, 20 the other.
    rows, cols = np.nonzero(np.isfinite(hf.z))
    assert np.ptp(cols) * hf.pixel_mm == pytest.approx(40, abs=1)
    assert np.ptp(rows) * hf.pixel_mm == pytest.approx(20, abs=1)
    (tmp_path / "d.yaml").write_text("up: +Y\n")
    hf, _ = H.load(path)
    assert hf.up["up"] == "+y" and np.nanmax(hf.z) == pytest.approx(20, abs=0.3)


def test_sidecar_up_refuses_other_words(tmp_path):
    verts, faces = hemisphere(20.0)
    _write_obj(tmp_path / "d.obj", verts, faces)
    (tmp_path / "d.yaml").write_text("up: north\n")
    with pytest.raises(InvalidSidecar) as e:
        H.load(tmp_path / "d.obj")
    assert e.value.code == "sidecar.value" and "up: y" in e.value.fix


def test_upside_down_mesh_turned_over(tmp_path):
    verts, faces = hemisphere(20.0)
    verts = verts * [1, -1, -1]    # turned over about x: apex down, normals still outward
    _write_obj(tmp_path / "b.obj", verts, faces)
    hf, _ = H.load(tmp_path / "b.obj")
    assert hf.up["up"] == "-z" and np.nanmax(hf.z) == pytest.approx(20, abs=0.3)
    r, c = np.array(hf.z.shape) // 2
    assert hf.z[r, c] == pytest.approx(20, abs=0.3)


def test_overhang_refused_with_share_and_fix(tmp_path):
    # A mushroom: a dome whose rim curls back under itself (a quarter of a torus).
    verts, faces = hemisphere(20.0, rings=30)
    t = np.arctan2(np.hypot(verts[:, 0], verts[:, 1]), verts[:, 2])   # 0 apex .. pi/2 rim
    curl = np.clip((t - np.pi / 3) / (np.pi / 6), 0, 1)                # last third curls
    ang = t + curl * np.pi / 2                                           # down to 3 pi / 4
    rad = 20.0 * np.sin(ang)
    phi = np.arctan2(verts[:, 1], verts[:, 0])
    verts = np.column_stack([rad * np.cos(phi), rad * np.sin(phi), 20.0 * np.cos(ang)])
    _write_obj(tmp_path / "m.obj", verts, faces)
    with pytest.raises(InvalidHeightField) as e:
        H.load(tmp_path / "m.obj")
    err = e.value
    assert err.code == "heightfield.not_a_heightfield"
    share = min(err.details["facing_away"].values())
    assert share > meshread.FACING_AWAY_MAX
    assert ("%.0f %%" % (100 * share)) in err.message
    assert "top surface" in err.fix and "up:" in err.fix


def test_closed_solid_refused(tmp_path):
    trimesh.creation.icosphere(subdivisions=3, radius=10.0).export(tmp_path / "ball.stl")
    with pytest.raises(InvalidHeightField) as e:
        H.load(tmp_path / "ball.stl")
    assert e.value.code == "heightfield.not_a_heightfield"
    assert all(s > 0.4 for s in e.value.details["facing_away"].values())


def test_closed_solid_taken_from_the_side_asked(tmp_path):
    trimesh.creation.icosphere(subdivisions=3, radius=10.0).export(tmp_path / "ball.stl")
    (tmp_path / "ball.yaml").write_text("up: z\npixel_mm: 0.5\n")
    hf, _ = H.load(tmp_path / "ball.stl")
    assert np.nanmax(hf.z) == pytest.approx(10.0, abs=0.3)
    assert hf.up["facing_away"] > 0.4


def test_terrain_block_with_base_and_walls_is_up(tmp_path):
    box = trimesh.creation.box(extents=(40, 30, 10))      # flat top and base, four walls
    verts = np.array(box.vertices)
    verts[:, 2] += verts[:, 0] * 0.05 * (verts[:, 2] > 0)  # a tilted top
    box = trimesh.Trimesh(verts, box.faces, process=False)
    box.export(tmp_path / "block.stl")
    (tmp_path / "block.yaml").write_text("pixel_mm: 1.0\n")
    hf, _ = H.load(tmp_path / "block.stl")
    assert hf.up["up"] == "+z" and hf.up["facing_away"] == 0.0


def test_a_y_up_cap_plans_upright_and_says_so(tmp_path):
    from hostd import planner
    from pipeline.profiles.profile import load_profile
    verts, faces = hemisphere(40.0, rings=12, segments=48, rim_deg=35.0)   # 46 mm, 7 mm high
    _write_obj(tmp_path / "cap.obj", _y_up(verts), faces)
    (tmp_path / "cap.yaml").write_text("pixel_mm: 1.0\n")
    plan = planner.run(tmp_path / "cap.obj", load_profile("generic-0.5mm"), tmp_path / "out")
    hf = plan.report["heightfield"]
    assert hf["up"]["up"] == "+y" and hf["max_height_mm"] == pytest.approx(
        40 * (1 - np.cos(np.radians(35))), rel=0.03)
    # Measured against the file as dropped, next to the plan's own figure.
    fid = plan.report["fidelity"]
    assert fid["relief_given_mm"] == pytest.approx(hf["max_height_mm"], rel=0.02)
    assert 0 < fid["mean_mm"] < 0.05 * hf["longest_diameter_mm"]
    assert fid["right_way_strong"] > 0.5
    assert "mesh read with +y up" in planner._input_note(plan)
