"""Printer profiles: shipped ones load, bad ones fail with stable codes naming the key."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.errors import InvalidProfile
from pipeline.profiles.profile import list_profiles, load_profile, parse_profile
from pipeline.profiles.schema import GCODE_PLACEHOLDERS
from pipeline.profiles.dump import profile_dict, profile_hash, profile_to_yaml

REPO = Path(__file__).resolve().parents[1]
SHIPPED = ["generic-0.5mm", "prusa-mk3s-0.4mm"]


def _minimal():
    return {"name": "t", "bed_mm": [200, 200], "nozzle_mm": 0.5, "filament_mm": 2.85,
            "path_width_mm": 0.48, "layers": 6, "thickness_mm": {"min": 0.1, "max": 0.45},
            "shrink_curve": {"degree": 4, "points": [[0.1, 0.343], [0.17, 0.25], [0.24, 0.169],
                                                     [0.31, 0.101], [0.38, 0.045], [0.45, 0.001]]}}


def _write(tmp_path, data, name="p.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _code(excinfo):
    return excinfo.value.code


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_profiles_load(name):
    p = load_profile(name)
    assert p.name == name
    assert Path(p.source).parent == REPO / "profiles"
    assert p.warnings == ()
    assert p.layers == 6
    # Decreasing curve: thinnest layer shrinks most.
    lo, hi = p.thickness_mm.min, p.thickness_mm.max
    assert p.shrink_curve.sigma(lo) > p.shrink_curve.sigma(hi)
    assert p.shrink_limits.s_min < p.shrink_limits.s_max <= p.shrink_curve.sigma_range[1] + 5e-3
    theta, clamped = p.shrink_curve.theta([p.shrink_limits.s_max, p.shrink_limits.s_min])
    assert lo - 1e-9 <= theta[0] < theta[1] <= hi + 1e-9
    # Real G-code: heat, wait, home; cancel turns heaters off.
    start, cancel = p.render_gcode("start"), p.render_gcode("cancel")
    for cmd in ("M104 S%g" % p.temperatures_c.hotend, "M140 S%g" % p.temperatures_c.bed,
                "M109", "M190", "G28"):
        assert cmd in start
    assert "M104 S0" in cancel and "M140 S0" in cancel and "M84" in cancel
    assert "{" not in start


def test_generic_profile_follows_the_paper():
    p = load_profile("generic-0.5mm")
    assert p.nozzle_mm == 0.5 and p.filament_mm == 2.85 and 0.48 <= p.path_width_mm <= 0.5
    assert p.shrink_curve.sigma(p.thickness_mm.min) == pytest.approx(0.343, abs=2e-3)
    assert p.shrink_curve.sigma(p.thickness_mm.max) == pytest.approx(0.0, abs=5e-3)
    assert p.shrink_limits.s_max == pytest.approx(0.343)
    assert "calibrat" in Path(p.source).read_text().lower()


def test_prusa_profile_is_a_175_printer():
    p = load_profile("prusa-mk3s-0.4mm")
    assert p.filament_mm == 1.75 and p.nozzle_mm == 0.4 and 0.42 <= p.path_width_mm <= 0.45
    assert p.bed_mm == (250.0, 210.0)
    assert "calibrat" in Path(p.source).read_text().lower()


def test_list_profiles_finds_shipped():
    found = list_profiles()
    assert set(SHIPPED) <= set(found)


def test_lookup_order_search_dirs_then_env(tmp_path, monkeypatch):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    _write(a, dict(_minimal(), name="from-a"), "mine.yaml")
    _write(b, dict(_minimal(), name="from-env"), "mine.yaml")
    _write(b, dict(_minimal(), name="only-env"), "other.yaml")
    monkeypatch.setenv("HOSTD_PROFILES", str(b))
    assert load_profile("mine", search_dirs=[a]).name == "from-a"
    assert load_profile("mine").name == "from-env"
    assert load_profile("other", search_dirs=[a]).name == "only-env"
    # A shipped name still resolves after the user dirs.
    assert load_profile("generic-0.5mm", search_dirs=[a]).name == "generic-0.5mm"


def test_load_by_path(tmp_path):
    path = _write(tmp_path, _minimal())
    p = load_profile(path)
    assert p.source == str(path)
    assert load_profile(str(path)).name == "t"


def test_omitted_sections_take_defaults(tmp_path):
    p = load_profile(_write(tmp_path, _minimal()))
    assert p.speeds_mm_s.print == 50 and p.temperatures_c.hotend == 215
    assert p.flatten.iterations == 50 and p.flatten.w_bending == 0.025
    assert p.mesh.l_u_mm == 0.25 and p.validate.max_fill_mm == 2.0
    assert p.defaults.size_mm == 150.0 and p.extrusion == "relative"


def test_the_constant_across_is_the_bilayers_until_it_is_set(tmp_path):
    data = _minimal()
    data["curvature"] = {"bilayer_c": 2.0, "across_c": None}
    cp = load_profile(_write(tmp_path, data)).curvature
    assert cp.across_c is None and cp.across_constant == 2.0
    assert cp.across_status == "uncalibrated"
    data["curvature"] = {"bilayer_c": 2.0, "across_c": 1.2, "across_status": "measured"}
    cp = load_profile(_write(tmp_path, data)).curvature
    assert cp.across_constant == 1.2 and cp.across_status == "measured"


@pytest.mark.parametrize("target", ["missing-profile-name", "no/such/file.yaml"])
def test_missing_profile(target, tmp_path):
    with pytest.raises(InvalidProfile) as e:
        load_profile(target, search_dirs=[tmp_path])
    assert _code(e) == "profile.not_found"
    assert e.value.fix


def test_bad_yaml_names_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nbed_mm: [1, 2\nnozzle_mm: 0.4\n")
    with pytest.raises(InvalidProfile) as e:
        load_profile(path)
    assert _code(e) == "profile.yaml" and "line" in e.value.where
    assert e.value.file == str(path)


def test_empty_file(tmp_path):
    path = tmp_path / "empty.yaml"
    path.write_text("")
    with pytest.raises(InvalidProfile) as e:
        load_profile(path)
    assert _code(e) == "profile.yaml"


@pytest.mark.parametrize("where,key", [((), "colour"), (("speeds_mm_s",), "prnt"),
                                       (("flatten",), "w_magic")])
def test_unknown_key_named(tmp_path, where, key):
    data = _minimal()
    d = data
    for w in where:
        d = d.setdefault(w, {})
    d[key] = 1
    path = _write(tmp_path, data)
    with pytest.raises(InvalidProfile) as e:
        load_profile(path)
    assert _code(e) == "profile.unknown_key"
    assert e.value.where == ".".join(where + (key,))
    assert e.value.file == str(path)


@pytest.mark.parametrize("key", ["name", "nozzle_mm", "layers", "thickness_mm", "shrink_curve"])
def test_missing_required_key(tmp_path, key):
    data = _minimal()
    del data[key]
    with pytest.raises(InvalidProfile) as e:
        load_profile(_write(tmp_path, data))
    assert _code(e) == "profile.missing_key" and e.value.where == key


@pytest.mark.parametrize("key,value,code", [
    ("nozzle_mm", "half", "profile.type"),
    ("layers", 6.5, "profile.type"),
    ("layers", True, "profile.type"),
    ("bed_mm", [200], "profile.type"),
    ("speeds_mm_s", {"print": "fast"}, "profile.type"),
    ("speeds_mm_s", 50, "profile.type"),
    ("extrusion", "sideways", "profile.value"),
    ("nozzle_mm", -0.4, "profile.value"),
    ("layers", 0, "profile.value"),
    ("path_width_mm", 1.5, "profile.value"),
    ("thickness_mm", {"min": 0.45, "max": 0.1}, "profile.value"),
    ("thickness_mm", {"min": 0.1, "max": 0.8}, "profile.value"),
    ("shrink_limits", {"s_min": 0.3, "s_max": 0.2}, "profile.value"),
    ("gcode", {"start": "M104 S{nozzle_temp}"}, "profile.value"),
    ("curvature", {"across_c": "same"}, "profile.type"),
    ("curvature", {"across_c": 0}, "profile.value"),
    ("curvature", {"across_status": "guessed"}, "profile.value"),
    ("curvature", {"bilayer_c": None}, "profile.type"),
])
def test_bad_values(tmp_path, key, value, code):
    data = _minimal()
    data[key] = value
    with pytest.raises(InvalidProfile) as e:
        load_profile(_write(tmp_path, data))
    assert _code(e) == code
    assert e.value.where.startswith(key)


def test_non_monotonic_curve(tmp_path):
    data = _minimal()
    # Shrink falls then rises again: one sigma would map to two thicknesses.
    data["shrink_curve"]["points"] = [[0.1, 0.30], [0.17, 0.18], [0.24, 0.10], [0.31, 0.08],
                                      [0.38, 0.15], [0.45, 0.25]]
    with pytest.raises(InvalidProfile) as e:
        load_profile(_write(tmp_path, data))
    assert _code(e) == "profile.shrink_not_monotonic"


def test_s_max_beyond_curve_is_clamped_and_said(tmp_path):
    data = _minimal()
    data["shrink_limits"] = {"s_min": 0.0, "s_max": 0.6}
    p = load_profile(_write(tmp_path, data))
    assert p.shrink_limits.s_max == pytest.approx(p.shrink_curve.sigma_range[1])
    assert any("s_max" in w for w in p.warnings)


def test_hash_is_canonical(tmp_path):
    data = _minimal()
    a = load_profile(_write(tmp_path, data, "a.yaml"))
    # Same content written differently (defaults spelled out, other key order) hashes the same.
    data2 = dict(reversed(list(data.items())), speeds_mm_s={"print": 50.0})
    b = load_profile(_write(tmp_path, data2, "b.yaml"))
    assert profile_hash(a) == profile_hash(b)
    data["layers"] = 5
    c = load_profile(_write(tmp_path, data, "c.yaml"))
    assert profile_hash(c) != profile_hash(a)


@pytest.mark.parametrize("name", SHIPPED)
def test_profile_to_yaml_round_trip(name, tmp_path):
    p = load_profile(name)
    text = profile_to_yaml(p, comment="calibrated\n2024")
    assert text.startswith("# calibrated\n# 2024\n")
    path = tmp_path / "copy.yaml"
    path.write_text(text)
    q = load_profile(path)
    assert profile_hash(q) == profile_hash(p)
    assert q.gcode.start == p.gcode.start


def test_profile_to_yaml_applies_and_validates_changes(tmp_path):
    p = load_profile("generic-0.5mm")
    pts = [[0.1, 0.30], [0.17, 0.22], [0.24, 0.15], [0.31, 0.09], [0.38, 0.04], [0.45, 0.002]]
    text = profile_to_yaml(p, shrink_curve={"points": pts}, shrink_limits={"s_max": 0.3})
    q = parse_profile(yaml.safe_load(text))
    assert q.shrink_curve.degree == 4
    np.testing.assert_allclose(q.shrink_curve.shrink, [s for _, s in pts])
    assert q.shrink_limits.s_max == pytest.approx(0.3, abs=5e-3)
    assert q.speeds_mm_s == p.speeds_mm_s
    with pytest.raises(InvalidProfile) as e:
        profile_to_yaml(p, shrink_curve={"points": [[0.1, 0.3], [0.2, 0.1], [0.3, 0.3],
                                                    [0.4, 0.1], [0.45, 0.3]]})
    assert _code(e).startswith("profile.shrink")


def test_gcode_vars_cover_placeholders():
    p = load_profile("generic-0.5mm")
    assert set(p.gcode_vars()) == set(GCODE_PLACEHOLDERS)
    assert p.gcode_vars()["retract_f"] == "2100"


def test_profile_dict_has_every_section():
    d = profile_dict(load_profile("generic-0.5mm"))
    for key in ("bed_mm", "shrink_curve", "shrink_limits", "gcode", "mesh", "flatten",
                "toolpath", "validate", "defaults", "serial", "retraction"):
        assert key in d
