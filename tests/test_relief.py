"""A sheet that misses its shape by much of its relief is told as such, however small a
share of its diameter that is."""

import numpy as np

from pipeline.input import shapes
from pipeline.plan import plan_file
from pipeline.problems import RELIEF_LOST, relief_problems
from pipeline.profiles.profile import load_profile

PROFILE = load_profile("generic-0.5mm")


def _plan(tmp_path, name, z, pixel_mm, extra=""):
    np.save(tmp_path / (name + ".npy"), np.asarray(z, np.float32))
    (tmp_path / (name + ".yaml")).write_text("pixel_mm: %r\nmin_prominence_mm: 0\n%s"
                                             % (pixel_mm, extra))
    return plan_file(tmp_path / (name + ".npy"), PROFILE, method="free")


def test_bumps_narrower_than_the_sheet_bends_are_told_to_hardly_show(tmp_path):
    """An egg crate of 8 mm wavelength on a 60 mm sheet: the plan is printable (a
    fraction of a millimetre off, under 1 % of the diameter), yet the bumps barely rise.
    Planned as given (``fit: off``): the fit would smooth them away, being beyond reach."""
    y, x = np.mgrid[0:121, 0:121] * 0.5
    z = 1.5 * (1 + np.sin(2 * np.pi * x / 8.0) * np.sin(2 * np.pi * y / 8.0))
    plan = _plan(tmp_path, "crate", z, 0.5, "fit: off\n")
    assert not plan.report["curvature"]["reach"]["within"]
    sim = plan.report["simulation"]
    assert sim["mean_displacement_fraction"] < 0.01
    assert sim["mean_displacement_of_relief"] > RELIEF_LOST
    assert sim["relief_mm"] == float(np.nanmax(plan.hf.z) - np.nanmin(plan.hf.z))
    [w] = [w for w in plan.report["warnings"] if w["code"] == "simulate.relief"]
    assert "hardly show" in w["message"] and "crate.yaml" in w["fix"]


def test_a_dome_that_forms_is_not_told(tmp_path):
    hf = shapes.dome(diameter_mm=60.0, height_mm=12.0)
    plan = _plan(tmp_path, "dome", hf.z, hf.pixel_mm)
    assert plan.report["simulation"]["mean_displacement_of_relief"] < 0.1
    assert "simulate.relief" not in [w["code"] for w in plan.report["warnings"]]


def test_the_warning_is_on_the_share_of_the_relief():
    assert relief_problems(2.0, 10.0, "x") == []
    [w] = relief_problems(3.0, 10.0, "x")
    assert "3.0 mm" in w["message"] and "30 %" in w["message"] and "10.0 mm" in w["message"]
    assert relief_problems(1.0, 0.0, "x") == []
