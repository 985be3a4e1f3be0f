"""A free sheet that does not hold its shape says at which smoothing it would, and that
smoothing, written in the sidecar, plans a sheet that holds it."""

import dataclasses

import numpy as np

from pipeline.input import shapes
from pipeline.plan import plan_file
from pipeline.profiles.profile import load_profile


def _ridged(tmp_path, extra="", fit="relief"):
    # Ridges a few mm across on a 60 mm starfish: the sheet rises as one smooth hill.
    # With `fit: relief` the fit does not smooth them away by itself: the look is asked.
    hf = shapes.starfish_ridged(diameter_mm=60.0, height_mm=12.0)
    path = tmp_path / "ridged.npy"
    np.save(path, hf.z)
    path.with_name("ridged.yaml").write_text("pixel_mm: %r\nmethod: free\nfit: %s\n%s"
                                              % (float(hf.pixel_mm), fit, extra))
    return path


def test_ridges_nobody_asked_a_height_for_are_smoothed_until_the_sheet_holds(tmp_path):
    """``fit: auto``: the fit smooths the ridges the stack cannot curl into, and the
    sheet then holds its shape without a look."""
    r = plan_file(_ridged(tmp_path, fit="auto"), load_profile("generic-0.5mm")).report
    assert r["fit"]["applied_smooth_mm"] is not None and not r["fit"]["reach_given"]["within"]
    assert r["curvature"]["reach"]["within"]
    assert r["printable"], r["gate"]
    assert "hold" not in r


def test_a_sheet_that_does_not_hold_is_offered_the_smoothing_that_does(tmp_path):
    prof = load_profile("generic-0.5mm")
    stages = []
    r = plan_file(_ridged(tmp_path), prof, progress=lambda s, m: stages.append(s)).report
    assert "printable.displacement" in r["gate"]["outside"]
    assert stages[-2:] == ["other_method", "hold"]     # the status page says what runs
    hold = r["hold"]
    assert hold["smooth_mm"] is not None and hold["smooth_mm"] > 1.0
    assert all(t[1] > prof.printable.max_mean_displacement
               for t in hold["tried"] if t[0] < hold["smooth_mm"])
    note = [w for w in r["warnings"] if w["code"] == "plan.hold"]
    line = "smooth_mm: %g" % hold["smooth_mm"]
    assert note and line in note[0]["fix"] and "ridged.yaml" in note[0]["fix"]
    # Following the note: the plan of the smoothed relief holds its shape.
    again = plan_file(_ridged(tmp_path, line + "\n"), prof).report
    assert again["printable"], again["gate"]
    assert "hold" not in again


def test_a_sheet_no_smoothing_holds_says_so(tmp_path):
    prof = load_profile("generic-0.5mm")
    prof = dataclasses.replace(prof, printable=dataclasses.replace(
        prof.printable, max_mean_displacement=1e-6))
    r = plan_file(_ridged(tmp_path), prof).report
    assert r["hold"]["smooth_mm"] is None and r["hold"]["tried"]
    assert max(t[0] for t in r["hold"]["tried"]) <= r["hold"]["cap_mm"]
    note = [w for w in r["warnings"] if w["code"] == "plan.hold"][0]
    assert "still ends" in note["message"] and "height_mm" in note["fix"]


def test_a_sheet_that_holds_is_not_looked_at(tmp_path):
    r = plan_file(_ridged(tmp_path, "smooth_mm: 5\n"), load_profile("generic-0.5mm")).report
    assert r["printable"] and "hold" not in r and "other_method" not in r


def test_a_look_that_cannot_plan_leaves_the_plan_standing(tmp_path, monkeypatch):
    from pipeline import alternatives
    from pipeline.errors import MeshingError

    def fails(*args, **kwargs):
        raise MeshingError("nothing left to mesh", code="mesh.empty")

    monkeypatch.setattr(alternatives, "build_grid_mesh", fails)
    monkeypatch.setattr(alternatives, "flatten", fails)
    r = plan_file(_ridged(tmp_path), load_profile("generic-0.5mm")).report
    assert "printable.displacement" in r["gate"]["outside"]
    assert r["hold"]["smooth_mm"] is None and r["hold"]["tried"] == []
    assert r["hold"]["failed"] and all(code == "mesh.empty" for _, code in r["hold"]["failed"])
    assert r["other_method"]["error"] == "mesh.empty"
    assert "plan.hold" not in [w["code"] for w in r["warnings"]]


def test_a_look_whose_relief_does_not_show_does_not_hold(monkeypatch):
    """Within the profile's share of the diameter is not enough: a look holds only where
    the sheet also misses by at most a quarter of its relief."""
    from pipeline import alternatives
    from pipeline.input.validate import validate
    prof = load_profile("generic-0.5mm")
    lenient = dataclasses.replace(prof, printable=dataclasses.replace(
        prof.printable, max_mean_displacement=1.0))
    hf, _ = validate(shapes.starfish_ridged(diameter_mm=60.0, height_mm=12.0), 2.0)
    opts = {"min_prominence_mm": 2.0, "smooth_mm": 1.0}
    held = alternatives.smoothing_that_holds(hf, lenient, opts, 60.0, fit_height_too=False)
    assert held["smooth_mm"] is not None
    assert all(t[4] <= alternatives.RELIEF_LOST for t in held["tried"]
               if t[0] == held["smooth_mm"])
    monkeypatch.setattr(alternatives, "RELIEF_LOST", 1e-6)
    none = alternatives.smoothing_that_holds(hf, lenient, opts, 60.0, fit_height_too=False)
    assert none["smooth_mm"] is None and all(t[4] > 1e-6 for t in none["tried"])


def test_each_look_simulates_the_sheet_as_the_plan_would_print_it(monkeypatch):
    """The advice is for the plan that follows it: each look settles the sheet with the
    twist and the layers across tried, as the plan does, not along d only (which asked
    the real tiles for 4 and 6 mm where 3 and 4 hold)."""
    from pipeline import alternatives
    from pipeline.input.validate import validate
    from pipeline.simulation import programmed
    calls = []

    def recorded(*args, **kwargs):
        calls.append(kwargs)
        return programmed.simulate_free(*args, **kwargs)
    monkeypatch.setattr(alternatives, "simulate_free", recorded)
    prof = load_profile("generic-0.5mm")
    hf, _ = validate(shapes.starfish_ridged(diameter_mm=60.0, height_mm=12.0), 2.0)
    held = alternatives.smoothing_that_holds(hf, prof, {"min_prominence_mm": 2.0, "smooth_mm": 1.0},
                                             60.0, fit_height_too=False)
    assert calls and len(calls) == len(held["tried"])
    assert all(kw.get("twist", True) and kw.get("across", True) for kw in calls)


def test_a_fit_that_lays_out_but_does_not_hold_takes_the_smoothing_that_holds(tmp_path):
    """Nobody asked for a height and the fit may smooth: the plan does not wait for a
    person to write the smoothing its own look found, it plans with it and says so."""
    hf = shapes.terrain_tile(width_mm=60.0, depth_mm=45.0, height_mm=12.0)
    path = tmp_path / "tile.npy"
    np.save(path, hf.z)
    path.with_name("tile.yaml").write_text("pixel_mm: %r\nmethod: free\n" % float(hf.pixel_mm))
    prof = load_profile("generic-0.5mm")
    # As given the tile lays out and ends 0.36 % of its diameter off; smoothed 3-4 mm,
    # under 0.3 %: a profile allowing 0.32 % holds it only smoothed.
    prof = dataclasses.replace(prof, printable=dataclasses.replace(
        prof.printable, max_mean_displacement=0.0032))
    r = plan_file(path, prof).report
    assert r["printable"], r["gate"]
    held = r["fit"]["held"]
    assert held["smooth_mm"] == r["hold"]["smooth_mm"] == r["fit"]["smooth_mm"] > 1.0
    assert held["first_mean_displacement_fraction"] > 0.0032
    assert r["simulation"]["mean_displacement_fraction"] <= 0.0032
    note = [w for w in r["warnings"] if w["code"] == "fit.held"]
    assert note and ("smoothed %g mm instead of 1 mm" % held["smooth_mm"]) in note[0]["message"]
    assert not [w for w in r["warnings"] if w["code"] in ("plan.hold", "printable.displacement")]
