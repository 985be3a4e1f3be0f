"""`hostd plan`: outputs, the report contract, and bad input leaving only an explanation."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from hostd.planner import output_names
from pipeline.input import shapes

# The report keys other tools read: renaming any is a breaking change.
CONTRACT = {
    "input": str, "profile": str, "pipeline_version": str,
    "heightfield": {"shape": list, "longest_diameter_mm": float, "max_height_mm": float,
                    "filled_pits": int, "filled_volume_mm3": float},
    "mesh": {"vertices": int, "triangles": int, "printing_edges": int, "bridge_edges": int,
             "isolines": int, "saddles": int, "peaks": int},
    "flatten": {"iterations": int, "converged": bool, "max_abs_z_mm": float,
                "flipped_triangles": int, "invalid_edge_fraction": float,
                "sigma": {"min": float, "p05": float, "mean": float, "p95": float, "max": float},
                "bridge_strain": {"mean_abs": float, "max_abs": float}},
    "simulation": {"mean_displacement_mm": float, "max_displacement_mm": float},
    "toolpath": {"traces": int, "segments": int, "length_mm": float, "travel_moves": int,
                 "sharp_turns": int, "coverage": float, "overlap": float,
                 "spacing_mm": {"target": float, "p05": float, "p50": float, "p95": float}},
    "gcode": {"lines": int, "bytes": int, "layers": int,
              "thickness_mm": {"min": float, "max": float}, "clamped_segments": int,
              "filament_mm": float, "estimated_print_s": float, "bed_fits": bool},
    "timing_s": {"load": float, "validate": float, "mesh": float, "flatten": float,
                 "simulate": float, "total": float, "toolpath": float, "gcode": float,
                 "texture": float},
}


def check_contract(report, spec, where="report"):
    for key, kind in spec.items():
        assert key in report, "%s lacks %r" % (where, key)
        if isinstance(kind, dict):
            check_contract(report[key], kind, where + "." + key)
        elif kind is float:
            assert isinstance(report[key], (int, float)) and not isinstance(report[key], bool), \
                "%s.%s is %r" % (where, key, report[key])
        else:
            assert isinstance(report[key], kind), "%s.%s is %r" % (where, key, report[key])


def hostd(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "hostd", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def small_dome(tmp_path_factory):
    d = tmp_path_factory.mktemp("in")
    hf = shapes.dome(diameter_mm=60.0, height_mm=12.0)
    np.save(d / "dome.npy", hf.z.astype(np.float32))
    (d / "dome.yaml").write_text("pixel_mm: 0.5\n")
    return d / "dome.npy"


@pytest.mark.slow
def test_plan_writes_every_output_and_the_report_contract(small_dome, tmp_path):
    out = tmp_path / "out"
    r = hostd("plan", small_dome, "--profile", "generic-0.5mm", "-o", out)
    assert r.returncode == 0, r.stderr
    names = sorted(os.listdir(out))
    assert names == sorted("dome." + k for k in (
        "report.json", "gcode", "flat.ply", "simulated.ply", "stress.png", "preview.png",
        "toolpath.png", "input.png"))
    report = json.loads((out / "dome.report.json").read_text())
    check_contract(report, CONTRACT)
    assert report["input"] == "dome.npy" and report["profile"] == "generic-0.5mm"
    assert report["gcode"]["bytes"] == (out / "dome.gcode").stat().st_size
    assert "invalid edges" in r.stdout
    # Added beside the contract: how far the paths turn away from the isolines.
    angle = report["toolpath"]["isoline_angle_deg"]
    assert set(angle) == {"p50", "p95"} and 0.0 <= angle["p50"] <= angle["p95"] <= 90.0


BAD_INPUTS = {
    "empty.png": (b"", "heightfield.empty"),
    "text.png": (b"this is not an image\n" * 10, "heightfield.content_mismatch"),
    "trunc.png": (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x01\x00", "heightfield.truncated"),
    "data.csv": (b"1,2,3\n", "heightfield.unsupported_type"),
}


@pytest.mark.parametrize("name", sorted(BAD_INPUTS))
def test_bad_input_gets_its_code_and_an_error_file_and_nothing_else(name, tmp_path):
    data, code = BAD_INPUTS[name]
    src = tmp_path / name
    src.write_bytes(data)
    out = tmp_path / "out"
    r = hostd("plan", src, "-o", out)
    assert r.returncode == 2
    assert code in r.stderr
    stem = src.stem
    assert sorted(os.listdir(out)) == [stem + ".error.json"]   # no half-written outputs
    err = json.loads((out / (stem + ".error.json")).read_text())
    assert err["code"] == code and err["input"] == name and err["fix"]
    assert src.read_bytes() == data                              # the input is untouched


def test_invalid_shape_is_refused_with_location(tmp_path):
    # A bowl: a crater at the summit deeper than max_fill_mm.
    hf = shapes.dome(diameter_mm=60.0, height_mm=12.0)
    rows, cols = np.indices(hf.z.shape)
    c = (np.array(hf.z.shape) - 1) / 2
    crater = np.hypot(rows - c[0], cols - c[1]) < 12
    z = np.where(crater, hf.z - 6.0, hf.z)
    np.save(tmp_path / "bowl.npy", z.astype(np.float32))
    (tmp_path / "bowl.yaml").write_text("pixel_mm: 0.5\n")
    r = hostd("plan", tmp_path / "bowl.npy", "-o", tmp_path / "out")
    assert r.returncode == 2
    err = json.loads((tmp_path / "out" / "bowl.error.json").read_text())
    assert err["code"] == "validate.depression"
    assert "max_fill_mm" in err["text"]
    assert os.listdir(tmp_path / "out") == ["bowl.error.json"]


def test_unknown_profile_is_a_clear_error(small_dome, tmp_path):
    r = hostd("plan", small_dome, "--profile", "no-such-printer", "-o", tmp_path)
    assert r.returncode == 3
    assert "profile.not_found" in r.stderr


def test_staging_is_discarded_when_writing_fails(small_dome, tmp_path, monkeypatch):
    from hostd import outputs
    st = outputs.Staging(tmp_path)
    st.write("a.txt", "x")
    with pytest.raises(RuntimeError):
        with st:
            raise RuntimeError("disk full")
    assert os.listdir(tmp_path) == []


def test_sidecar_overrides_the_simplification_settings(tmp_path):
    from pipeline.input.sidecar import load_sidecar, settings
    from pipeline.profiles.profile import load_profile
    side = tmp_path / "x.yaml"
    side.write_text("min_prominence_mm: 6\nsmooth_mm: 3.5\nmax_fill_mm: 4\n")
    opts = settings(load_sidecar(side), load_profile("generic-0.5mm"))
    assert opts == {"max_fill_mm": 4.0, "min_prominence_mm": 6.0, "smooth_mm": 3.5}


@pytest.mark.slow
def test_real_terrain_plans_and_says_whether_it_is_printable(terrain_dir, tmp_path):
    # The real tile at 60 mm (its relief and pits scaled with it): the same terrain, a
    # third of the plan time of its full 112 mm.
    src = tmp_path / "vancouver_island_south.png"
    src.write_bytes((terrain_dir / src.name).read_bytes())
    src.with_suffix(".yaml").write_text("size_mm: 60\nheight_mm: 18.5\nmax_fill_mm: 5.0\n"
                                        "method: isoline\n")
    r = hostd("plan", src, "-o", tmp_path)
    assert r.returncode in (0, 4), r.stderr
    report = json.loads((tmp_path / "vancouver_island_south.report.json").read_text())
    check_contract(report, CONTRACT)
    assert report["heightfield"]["filled_pits"] > 0          # real pits, filled per its sidecar
    assert report["mesh"]["isolines"] > report["mesh"]["peaks"]
    # Exit status 4 exactly when the plan is marked not printable, with the reason printed.
    assert (r.returncode == 4) == (report["printable"] is False)
    for w in report["warnings"]:
        assert w["code"] in r.stderr


def test_layout_problems_name_the_fix_that_helps_and_split_the_invalid_edges():
    """A folded layout's fix is smoothing (what turned the folded real terrain
    printable; a lower height and more iterations made it fold more), and the
    invalid-edge problem says how many edges would have to stretch and how many
    shrink too much, since the two have different fixes."""
    from types import SimpleNamespace
    from pipeline.problems import FOLD_LIMIT, layout_problems
    from pipeline.profiles.profile import load_profile
    lim = load_profile("generic-0.5mm").shrink_limits
    sigma = np.concatenate([np.full(70, 0.1), np.full(20, -0.05), np.full(10, lim.s_max + 0.1)])
    flat = SimpleNamespace(overlapping=True, flipped_triangles=12, boundary_intersections=1,
                           invalid_edge_fraction=0.30, sigma=sigma)
    fold, invalid = layout_problems(flat, 2 * FOLD_LIMIT, lim)
    assert fold["code"] == "flatten.overlap"
    assert "smooth_mm" in fold["fix"] and "iterations do not help" in fold["fix"]
    assert invalid["code"] == "flatten.invalid_edges"
    assert "30.0 %" in invalid["message"]
    assert "20.0 % would have to stretch, 10.0 % shrink more" in invalid["message"]
    assert [p["code"] for p in layout_problems(flat, FOLD_LIMIT / 2, lim)][0] == \
        "flatten.small_fold"
    # The advice starts from where the file stands, never below what it already has.
    fold5 = layout_problems(flat, 2 * FOLD_LIMIT, lim, "tile.yaml", smooth_mm=5.0)[0]
    assert "from 5, e.g. `smooth_mm: 10`" in fold5["fix"] and "tile.yaml" in fold5["fix"]
    assert "method: free" in fold5["fix"]
    flat.overlapping, flat.invalid_edge_fraction = False, 0.05
    assert layout_problems(flat, 0.0, lim) == []


def test_a_simulation_still_moving_is_a_warning_not_a_verdict():
    """A plan whose sheet did not come to rest says so (its displacement is
    where the sheet stood), without making the plan unprintable."""
    from types import SimpleNamespace
    from pipeline.plan import Plan
    from pipeline.problems import simulation_problems
    moving = SimpleNamespace(converged=False, iterations=600, mean_displacement_mm=3.96)
    (w,) = simulation_problems(moving)
    assert w["code"] == "simulate.not_at_rest"
    assert "600 iterations" in w["message"] and "3.96 mm" in w["message"] and w["fix"]
    assert simulation_problems(SimpleNamespace(converged=True)) == []
    plan = Plan(name="x", profile=None, problems=[w])
    assert plan.printable


def test_fold_area_fraction_measures_flipped_area():
    from pipeline.problems import fold_area_fraction
    xy = np.array([[0, 0], [1, 0], [0, 1], [1, 1.0]])
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    assert fold_area_fraction(xy, faces) == 0.0
    folded = xy.copy()
    folded[3] = [-0.5, -0.5]          # the second triangle flips over the first
    f = fold_area_fraction(folded, faces)
    assert 0.0 < f < 1.0
    assert f == pytest.approx(1.0 / (0.5 + 1.0))   # flipped area 1.0, total 1.5


@pytest.mark.slow
def test_colour_input_gets_a_screen_print_texture_and_outline(tmp_path):
    from PIL import Image
    hf = shapes.dome(diameter_mm=40.0, height_mm=8.0)
    np.save(tmp_path / "c.npy", hf.z.astype(np.float32))
    (tmp_path / "c.yaml").write_text("pixel_mm: 0.5\n")
    r_, c_ = np.indices(hf.z.shape)
    rgb = np.stack([c_ * 255 // c_.max(), r_ * 255 // r_.max(), np.full_like(r_, 128)], -1)
    Image.fromarray(rgb.astype(np.uint8)).save(tmp_path / "c.color.png")
    r = hostd("plan", tmp_path / "c.npy", "-o", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    # Exactly the files `hostd plan --help` lists (from the same list).
    assert sorted(os.listdir(tmp_path / "out")) == sorted(output_names("c", color=True).values())
    report = json.loads((tmp_path / "out" / "c.report.json").read_text())
    assert report["heightfield"]["has_color"] and report["texture"]["dpi"] == 300
    with Image.open(tmp_path / "out" / "c.texture.png") as im:
        assert round(im.info["dpi"][0]) == 300 and im.mode == "RGBA"
        px = np.asarray(im).astype(int)
    # Red grows to the east (image right), green to the south (image bottom); the
    # black registration marks are left out.
    inside = (px[..., 3] > 0) & (px[..., :3].sum(axis=-1) > 60)
    cols = np.nonzero(inside.any(axis=0))[0]
    rows = np.nonzero(inside.any(axis=1))[0]
    mid_r, mid_c = (rows[0] + rows[-1]) // 2, (cols[0] + cols[-1]) // 2
    assert px[mid_r, cols[-1] - 5, 0] > px[mid_r, cols[0] + 5, 0] + 100
    assert px[rows[-1] - 5, mid_c, 1] > px[rows[0] + 5, mid_c, 1] + 100
    assert "<svg" in (tmp_path / "out" / "c.outline.svg").read_text()
