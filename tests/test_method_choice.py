"""The layout method per file: a sidecar's ``method`` overrides the profile's, and a plan
one method cannot print says whether the other would."""

import dataclasses

import numpy as np
import pytest

from pipeline.errors import InvalidSidecar
from pipeline.input import shapes
from pipeline.input.sidecar import load_sidecar
from pipeline.plan import plan_file
from pipeline.profiles.profile import load_profile


def _saddle(tmp_path, method=None, height_mm=8.0):
    hf = shapes.hyperbolic_paraboloid(diameter_mm=40.0, height_mm=height_mm)
    path = tmp_path / "saddle.npy"
    np.save(path, np.nan_to_num(hf.z, nan=np.nan))
    side = "pixel_mm: %r\n" % float(hf.pixel_mm) + ("method: %s\n" % method if method else "")
    path.with_name("saddle.yaml").write_text(side)
    return path


def test_a_saddle_the_isoline_method_cannot_print_says_the_free_one_would(tmp_path):
    plan = plan_file(_saddle(tmp_path, "isoline"), load_profile("generic-0.5mm"))
    r = plan.report
    assert r["flatten"]["method"] == "isoline" and not r["printable"]
    assert r["other_method"]["would_form"] and r["other_method"]["flipped"] == 0
    note = [w for w in r["warnings"] if w["code"] == "plan.other_method"]
    assert note and "method: free" in note[0]["fix"] and "saddle.yaml" in note[0]["fix"]


def _dome(tmp_path, method):
    hf = shapes.dome(diameter_mm=15.0, height_mm=3.0)
    path = tmp_path / "dome.npy"
    np.save(path, hf.z)
    path.with_name("dome.yaml").write_text("pixel_mm: %r\nmethod: %s\n" % (hf.pixel_mm, method))
    return path


def _strict():
    """A profile whose displacement limit the free sheet of :func:`_dome` (0.6 % off)
    does not meet: a plan the free method cannot print for a reason the layout of the
    other method does not decide."""
    prof = load_profile("generic-0.5mm")
    return dataclasses.replace(prof, printable=dataclasses.replace(
        prof.printable, max_mean_displacement=0.002))


def test_a_dome_the_free_method_cannot_hold_says_the_isoline_one_would(tmp_path):
    # The thin shell holds this small, steep dome 0.6 % off, beyond the profile's limit;
    # the paper's layout forms it without folds.
    plan = plan_file(_dome(tmp_path, "free"), _strict())
    r = plan.report
    assert r["flatten"]["method"] == "free" and not r["printable"]
    assert r["other_method"]["method"] == "isoline" and r["other_method"]["would_form"]
    assert r["other_method"]["flipped"] == 0 and "other_method" in r["timing_s"]
    note = [w for w in r["warnings"] if w["code"] == "plan.other_method"]
    assert note and "method: isoline" in note[0]["fix"] and "dome.yaml" in note[0]["fix"]


def test_a_saddle_neither_method_prints_says_so(tmp_path):
    # A displacement limit no free plan meets: the free plan fails, and the paper's layout
    # of a saddle this steep leaves over a third of the sheet outside the material's range.
    prof = load_profile("generic-0.5mm")
    prof = dataclasses.replace(prof, printable=dataclasses.replace(
        prof.printable, max_mean_displacement=1e-6))
    r = plan_file(_saddle(tmp_path, "free", height_mm=12.0), prof).report
    assert not r["printable"] and not r["other_method"]["would_form"]
    assert r["other_method"]["method"] == "isoline"
    assert r["other_method"]["invalid_area_fraction"] > prof.printable.max_invalid_area
    note = [w for w in r["warnings"] if w["code"] == "plan.other_method"]
    assert note and "does not form it either" in note[0]["message"]


def test_the_sidecar_chooses_the_method(tmp_path):
    prof = load_profile("generic-0.5mm")
    assert prof.flatten.method == "free"
    plan = plan_file(_saddle(tmp_path, "isoline"), prof)
    assert plan.report["flatten"]["method"] == "isoline"
    assert plan.profile.flatten.method == "isoline"
    plan = plan_file(_saddle(tmp_path, "free"), prof)
    assert plan.report["flatten"]["method"] == "free" and plan.report["printable"]
    assert "other_method" not in plan.report


def test_an_unknown_method_is_refused_with_the_choices(tmp_path):
    (tmp_path / "x.yaml").write_text("method: diagonal\n")
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(tmp_path / "x.yaml")
    assert err.value.code == "sidecar.value" and "method: free" in str(err.value)


def test_an_isoline_mesher_that_stops_is_named_in_the_note(tmp_path, monkeypatch):
    from pipeline import alternatives
    from pipeline.errors import MeshingError

    def stops(*args, **kwargs):
        raise MeshingError("isolines cross", code="mesh.overlap", where="x 3 mm, y 4 mm",
                           fix="report it")

    monkeypatch.setattr(alternatives, "build_mesh", stops)
    r = plan_file(_dome(tmp_path, "free"), _strict()).report
    assert r["other_method"] == {"method": "isoline", "would_form": False,
                                 "error": "mesh.overlap",
                                 "error_message": r["other_method"]["error_message"]}
    note = [w for w in r["warnings"] if w["code"] == "plan.other_method"][0]
    assert "mesher stops: isolines cross (at x 3 mm, y 4 mm)" in note["message"]
    # The mesher's own fix is not nested in the note's message: the note has its own.
    assert "report it" not in note["message"] and "Fix" not in note["message"]
