"""The layout method per file: a sidecar's ``method`` overrides the profile's, and a plan
the paper's method cannot print says whether the free method would."""

import numpy as np
import pytest

from pipeline.errors import InvalidSidecar
from pipeline.input import shapes
from pipeline.input.sidecar import load_sidecar
from pipeline.plan import plan_file
from pipeline.profiles.profile import load_profile


def _saddle(tmp_path, method=None):
    hf = shapes.hyperbolic_paraboloid(diameter_mm=40.0, height_mm=8.0)
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


def test_the_sidecar_chooses_the_method(tmp_path):
    prof = load_profile("generic-0.5mm")
    assert prof.flatten.method == "free"
    plan = plan_file(_saddle(tmp_path, "isoline"), prof)
    assert plan.report["flatten"]["method"] == "isoline"
    assert plan.profile.flatten.method == "isoline"
    plan = plan_file(_saddle(tmp_path, "free"), prof)
    assert plan.report["flatten"]["method"] == "free" and "other_method" not in plan.report


def test_an_unknown_method_is_refused_with_the_choices(tmp_path):
    (tmp_path / "x.yaml").write_text("method: diagonal\n")
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(tmp_path / "x.yaml")
    assert err.value.code == "sidecar.value" and "method: free" in str(err.value)
