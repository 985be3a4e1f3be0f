"""Fit to the material: a relief too steep to form is lowered when nobody asked for it,
refused with the sidecar line that would form when somebody did, and kept when it forms."""

import dataclasses

import numpy as np
import pytest

from hostd import planner
from pipeline.geometry import HeightField
from pipeline.layout.fit import _close_in, fit_height, least_smoothing, scaled
from pipeline.layout.free import flatten_free
from pipeline.meshing.grid import build_grid_mesh
from pipeline.profiles.profile import load_profile

PROFILE = load_profile("generic-0.5mm")
FREE = dataclasses.replace(PROFILE, flatten=dataclasses.replace(PROFILE.flatten, method="free"))
LIM = PROFILE.shrink_limits


@pytest.fixture(autouse=True)
def _blank_pictures(monkeypatch):
    """The plans here are asserted on their reports, problems and error files, never on
    their pictures (test_plan_cli checks those are written): drawn blank, they cost
    nothing instead of a third of each plan."""
    from PIL import Image
    from pipeline.pictures import hfimage, render

    def blank(*args, **kwargs):
        return Image.new("RGB", (1, 1))
    for module, name in ((render, "toolpath_image"), (render, "stress_image"),
                         (render, "preview_image"), (hfimage, "heightfield_image")):
        monkeypatch.setattr(module, name, blank)


@pytest.fixture
def no_look(monkeypatch):
    """For the plans asserted on their fit alone: the looks at a plan the gate turned
    down (the other layout method, the hold; a third to half of such a plan) are not
    taken. test_a_refused_relief_whose_layout_leaves_the_bed_is_reported_by_its_own_fix
    and test_hold check them."""
    from pipeline import alternatives
    monkeypatch.setattr(alternatives, "look", lambda *args, **kwargs: None)


def _cone(height_mm, diameter_mm=60.0, px=0.5):
    n = int(diameter_mm / px) + 1
    y, x = np.mgrid[0:n, 0:n] * px
    r = np.hypot(x - diameter_mm / 2, y - diameter_mm / 2)
    # A rounded cone: slopes of atan(2 * height / diameter) on its flank.
    z = height_mm * np.clip(1 - np.sqrt(r ** 2 + 9.0) / (diameter_mm / 2), 0, None)
    z[r > diameter_mm / 2] = np.nan
    return HeightField(z, px, source="cone")


def _write(tmp_path, hf, sidecar):
    np.save(tmp_path / "cone.npy", hf.z)
    (tmp_path / "cone.yaml").write_text("pixel_mm: %r\n%s" % (hf.pixel_mm, sidecar))
    return tmp_path / "cone.npy"


def _invalid(hf, scale):
    flat = flatten_free(build_grid_mesh(scaled(hf, scale), 1.0), LIM.s_min, LIM.s_max)
    return flat.invalid_area_fraction


def test_the_fitted_height_is_within_five_percent_of_the_largest_that_forms():
    hf = _cone(45.0)                       # flanks of 56 degrees: steeper than 49
    fit = fit_height(hf, LIM.s_min, LIM.s_max)
    assert 0.3 < fit.applied_scale < 1.0
    # Planned slightly below and above the fitted height, on the plan's mesh.
    assert _invalid(hf, fit.applied_scale * 0.95) <= 0.02
    assert _invalid(hf, fit.applied_scale * 1.05) > 0.02


def test_a_relief_nobody_asked_for_is_lowered_to_what_forms(tmp_path):
    plan = planner.run(_write(tmp_path, _cone(45.0), ""), FREE, tmp_path / "out")
    r = plan.report
    assert r["fit"]["applied_scale"] < 1.0 and r["flatten"]["invalid_area_fraction"] <= 0.02
    assert plan.printable and "fit.lowered" in [p["code"] for p in r["warnings"]]
    assert set(r["fit"]) >= {"max_height_mm", "requested_height_mm", "applied_scale",
                             "smooth_mm", "reason", "min_smooth_mm"}
    # The fit's last solve was this layout, on the plan's mesh: the plan takes it.
    assert r["fit"]["layout_reused"] and plan.flat.xy is plan.fit.layout[1].xy


def test_a_relief_asked_for_is_refused_with_the_line_that_forms(tmp_path, no_look):
    plan = planner.run(_write(tmp_path, _cone(45.0), "height_mm: 45\n"), FREE, tmp_path / "out")
    assert not plan.printable
    [p] = [p for p in plan.problems if p["code"] == "fit.too_high"]
    line = plan.fit.sidecar_line()
    assert line in p["fix"] and "cone.yaml" in p["fix"]
    assert float(line.split(":")[1]) < 45.0


def test_the_sidecar_line_asks_for_the_height_before_smoothing(tmp_path, no_look):
    """The sidecar's height sets the input's top, which smoothing then lowers: written
    as suggested, the line plans the largest relief that forms, not one smoothing
    lowers again."""
    side = "height_mm: 45\nsmooth_mm: 3\n"
    plan = planner.run(_write(tmp_path, _cone(45.0), side), FREE, tmp_path / "out")
    fit = plan.fit
    [p] = [p for p in plan.problems if p["code"] == "fit.too_high"]
    assert "45.0 mm; %.1f mm once smoothed" % fit.requested_height_mm in p["message"]
    assert fit.requested_height_mm < 0.95 * 45.0
    line = fit.sidecar_line()
    again = planner.run(_write(tmp_path, _cone(45.0), side.replace("height_mm: 45", line)),
                        FREE, tmp_path / "again")
    relief = float(np.nanmax(again.hf.z) - np.nanmin(again.hf.z))
    assert relief == pytest.approx(fit.max_height_mm, rel=0.01)
    assert plan.report["fit"]["sidecar_height_mm"] == float(line.split(":")[1])


def test_a_refused_relief_whose_layout_leaves_the_bed_is_reported_by_its_own_fix(tmp_path):
    """Laid out at the height asked for, the cone's flat sheet is larger than the bed:
    the error a person reads is the relief's, with the sidecar line that forms, not a
    request for a smaller model (which would make the slopes steeper still)."""
    from pipeline.errors import PipelineError
    small_bed = dataclasses.replace(FREE, bed_mm=(61.0, 61.0))
    with pytest.raises(PipelineError) as err:
        planner.run(_write(tmp_path, _cone(45.0), "height_mm: 45\n"), small_bed,
                    tmp_path / "out")
    e = err.value
    assert e.code == "fit.too_high" and "height_mm: " in e.fix and "cone.yaml" in e.fix
    assert e.details["gcode"]["code"] == "gcode.off_bed"
    assert "does not fit the 61 x 61 mm bed" in e.message
    assert (tmp_path / "out" / "cone.error.json").exists()
    # Nor does the paper's method lay out a cone this steep, and the error says so.
    assert e.details["other_method"]["method"] == "isoline"
    assert not e.details["other_method"]["would_form"]
    assert "isoline) layout method does not form it either" in e.message


def test_fit_off_keeps_the_relief(tmp_path, no_look):
    plan = planner.run(_write(tmp_path, _cone(45.0), "fit: off\n"), FREE, tmp_path / "out")
    assert plan.fit is None and plan.report["flatten"]["invalid_area_fraction"] > 0.02


def test_a_relief_that_forms_is_left_as_it_is(tmp_path):
    plan = planner.run(_write(tmp_path, _cone(12.0), ""), FREE, tmp_path / "out")
    assert plan.report["fit"]["applied_scale"] == 1.0
    assert "fit.lowered" not in [p["code"] for p in plan.problems]
    # ... and needs no smoothing either: none is looked for.
    assert plan.report["fit"]["min_smooth_mm"] is None and plan.report["fit"]["smooth_tried"] == []


def _hill_with_a_spike(px=0.5):
    """A gentle 100 mm hill (8 mm) with a narrow spike on its flank (12 mm, 3 mm wide):
    the spike alone is too steep to form."""
    n = int(100 / px) + 1
    y, x = np.mgrid[0:n, 0:n] * px
    r = np.hypot(x - 50, y - 50)
    z = 8.0 * np.clip(1 - (r / 50) ** 2, 0, None)
    z += 12.0 * np.exp(-((x - 65) ** 2 + (y - 50) ** 2) / (2 * 3.0 ** 2))
    z[r > 50] = np.nan
    return HeightField(z, px, source="spike")


def _spike_plan(tmp_path, sidecar=""):
    hf = _hill_with_a_spike()
    np.save(tmp_path / "spike.npy", hf.z)
    (tmp_path / "spike.yaml").write_text("pixel_mm: %r\nsmooth_mm: 0.5\n%s" % (hf.pixel_mm,
                                                                            sidecar))
    return planner.run(tmp_path / "spike.npy", FREE, tmp_path / "out")


def test_a_narrow_spike_is_smoothed_and_the_relief_kept(tmp_path):
    """The second lever comes first where nobody asked for a height: the least smoothing
    at which the relief as given lays out and lies within reach is applied, the relief
    is not lowered, and the warning says how far the smoothing moved the surface."""
    plan = _spike_plan(tmp_path)
    fit = plan.report["fit"]
    assert fit["applied_scale"] == 1.0
    assert fit["applied_smooth_mm"] == fit["min_smooth_mm"] and fit["min_smooth_mm"] <= 5.0
    areas = {s: a for s, a, _ in fit["smooth_tried"]}
    reach = dict(fit["smooth_reach"])
    assert areas[fit["min_smooth_mm"]] <= 0.02 and reach[fit["min_smooth_mm"]] <= 0.4
    assert all(areas[s] > 0.02 or reach[s] > 0.4 for s in areas if s < fit["min_smooth_mm"])
    assert plan.report["flatten"]["invalid_area_fraction"] <= 0.02
    # The plan's field is the input smoothed that much: lower peaks, same hill.
    relief = float(np.nanmax(plan.hf.z) - np.nanmin(plan.hf.z))
    assert relief == pytest.approx(fit["max_height_mm"], abs=0.01)
    assert fit["removed_mm"] > 0
    [smoothed] = [p for p in plan.problems if p["code"] == "fit.smoothed"]
    assert "smoothed %g mm" % fit["applied_smooth_mm"] in smoothed["message"]
    assert "fit: relief" in smoothed["fix"]
    assert "fit.lowered" not in [p["code"] for p in plan.problems]
    # Its curvature program reads the input smoothed only half as much.
    off = [float(np.nanmean(np.abs(z - plan.validated.z))) for z in (plan.relief.z, plan.hf.z)]
    assert 0 < off[0] < 0.7 * off[1]
    assert "smoothed %g mm to form" % fit["applied_smooth_mm"] in planner.preview_title(plan)
    assert "smoothed %g mm by the fit" % fit["applied_smooth_mm"] in planner._input_note(plan)
    # What would form the spike as given, said in the warning: its slopes as given are
    # the first solve's; too steep, no size forms them, only a lower or smoother relief.
    keep = fit["keep"]
    scale, area, flips = fit["tried"][0]
    assert scale == 1.0 and keep["slopes_form"] == (area <= 0.02 and flips == 0)
    # The fit had to smooth, so the input as given fails one of the two limits: its
    # slopes, or its curvature at this size.
    assert not keep["slopes_form"] or keep["size_factor"] > 1.0
    if keep["slopes_form"]:
        assert "`size_mm: %d`" % np.ceil(keep["size_mm_as_given"]) in smoothed["message"]
    else:
        assert keep["size_mm_as_given"] is None
        assert "only a lower or smoother relief" in smoothed["message"]


def test_fit_relief_lowers_the_spike_and_offers_the_smoothing(tmp_path, no_look):
    """``fit: relief`` keeps the first lever only: the relief is lowered and the least
    smoothing that would form it at full height is named in the fix."""
    plan = _spike_plan(tmp_path, "fit: relief\n")
    fit = plan.report["fit"]
    assert fit["applied_scale"] < 1.0 and fit["applied_smooth_mm"] is None
    assert fit["min_smooth_mm"] is not None and fit["min_smooth_mm"] <= 5.0
    areas = {s: a for s, a, _ in fit["smooth_tried"]}
    assert areas[fit["min_smooth_mm"]] <= 0.02
    [lowered] = [p for p in plan.problems if p["code"] == "fit.lowered"]
    assert "smooth_mm: %g" % fit["min_smooth_mm"] in lowered["fix"]
    assert fit["removed_mm"] > 0
    assert "relief lowered from" in planner.preview_title(plan)


def test_a_height_asked_for_that_a_smoothing_forms_is_offered_the_smoothing_first(tmp_path, no_look):
    """The smoothing that keeps the height changes the input least: the fix names it
    before the lower height."""
    plan = _spike_plan(tmp_path, "height_mm: 20\n")
    [p] = [p for p in plan.problems if p["code"] == "fit.too_high"]
    smooth = "smooth_mm: %g" % plan.fit.min_smooth_mm
    assert smooth in p["fix"] and "spike.yaml" in p["fix"]
    assert p["fix"].index(smooth) < p["fix"].index(plan.fit.sidecar_line())


def _ribs(amplitude_mm, px=0.5):
    """A 90 mm square of ribs 6 mm apart, ``amplitude_mm`` high, on a gentle hill: slopes
    any sheet lays out, curvature no sheet of a millimetre and more curls into."""
    n = int(90 / px) + 1
    y, x = np.mgrid[0:n, 0:n] * px
    z = 4.0 * np.exp(-((x - 45) ** 2 + (y - 45) ** 2) / (2 * 25.0 ** 2))
    z += amplitude_mm * np.sin(2 * np.pi * x / 6.0)
    return HeightField(z, px, source="ribs")


def test_ribs_that_lay_out_but_bend_beyond_reach_are_smoothed_away():
    """The layout of the ribs forms as given; their curvature does not: the fit smooths
    them (``fit: auto``), and with the first lever only keeps the relief as it is and
    says why."""
    from pipeline.layout.reach import reach
    hf = _ribs(0.6)

    def resmooth(s):
        from pipeline.input.simplify import simplify
        return simplify(hf, 0.0, s)[0]
    reach_of = lambda field, mesh, flat: reach(field, mesh, flat, PROFILE)
    auto = fit_height(hf, LIM.s_min, LIM.s_max, resmooth=resmooth, reach_of=reach_of,
                      smooth_first=True)
    assert auto.tried[0][1] <= 0.02                      # lays out as given
    assert not auto.reach_given["within"] and auto.reach_given["p90"] > 1.0
    assert auto.applied_smooth_mm is not None and auto.applied_scale == 1.0
    assert dict(auto.smooth_reach)[auto.applied_smooth_mm] <= 0.4
    relief_only = fit_height(hf, LIM.s_min, LIM.s_max, resmooth=resmooth, reach_of=reach_of)
    assert relief_only.applied_scale == 1.0 and relief_only.applied_smooth_mm is None
    assert relief_only.reason == "forms as given"


@pytest.mark.parametrize("power,solves", [(1, 4), (4, 8)])
def test_false_position_closes_in_on_a_smooth_area(power, solves):
    """An invalid-area curve crossing 2 % at 0.5: the bracket 0.1 .. 1 narrows to within
    3 % in ``solves`` solves (bisection: six). A gentle curve, as real terrain's, takes
    fewer; a steep one (a cone's flank reaching the limit all at once) a few more."""
    tried = [(0.1, 0.0, 0), (1.0, 0.02 * 2 ** power, 0)]

    def ok(scale, spacing, iterations):
        area = 0.02 * (scale / 0.5) ** power
        tried.append((scale, area, 0))
        return area <= 0.02
    a, b = _close_in(ok, tried, 0.1, 1.0, 0.02, 10, 1.0, 100)
    assert a <= 0.5 < b and b - a < 0.03 * b and len(tried) - 2 <= solves


def test_an_area_that_rises_all_at_once_is_bisected_not_crept_up_on():
    """A cone's flank passes the limit together: no invalid area up to 0.84, then most
    of the sheet. False position from 0.65 .. 0.9 would creep up by tenths of the bracket;
    five solves land within 3 %."""
    area = lambda s: float(np.interp(s, [0.84, 0.86, 0.9], [0.005, 0.03, 0.6]))
    tried = [(0.65, 0.0, 0), (0.9, area(0.9), 0)]

    def ok(scale, spacing, iterations):
        tried.append((scale, area(scale), 0))
        return area(scale) <= 0.02
    a, b = _close_in(ok, tried, 0.65, 0.9, 0.02, 5, 1.0, 100, area_a=0.0)
    assert a <= 0.852 < b and b - a < 0.03 * b


@pytest.mark.parametrize("forms_from,least", [(2.7, 3.0), (3.2, 4.0), (1.5, 1.5), (1.7, 2.0), (30, None)])
def test_the_least_smoothing_is_found_to_a_quarter_in_a_few_solves(forms_from, least):
    """Doubling from 2 mm, then once halfway back: 3 mm where 2 does not form and 3 does,
    not the ladder's 4; none up to the cap is None."""
    tried = []

    def forms(smooth):
        tried.append(smooth)
        return smooth >= forms_from
    assert least_smoothing(forms, 1.0, cap_mm=10.0) == least
    assert len(tried) <= 4


def test_plan_fit_prints_the_smoothing_solves_beside_the_scales(capsys):
    from hostd.commands.plan import _print_fit
    _print_fit({"tried": [[1.0, 0.3, 0], [0.5, 0.01, 0]], "smooth_tried": [[2.0, 0.05, 0],
                                                                          [1.5, 0.3, 0]],
                "min_smooth_mm": 2.0, "max_height_mm": 5.0, "requested_height_mm": 10.0,
                "applied_scale": 0.5, "solves": 2, "seconds": 3.0, "smooth_seconds": 1.0,
                "reason": "steep"})
    out = capsys.readouterr().out
    assert "smooth_mm" in out and "1.5        30.00 %" in out
    assert "4 solves in 3.0 s (1.0 s of them smoothing)" in out
    assert "forms with smooth_mm: 2" in out


def test_plan_fit_prints_the_reach_and_the_smoothing_applied(capsys):
    from hostd.commands.plan import _print_fit
    _print_fit({"tried": [[1.0, 0.3, 0]], "smooth_tried": [[2.0, 0.05, 0], [4.0, 0.0, 0]],
                "smooth_reach": [[4.0, 0.31]], "reach_given": {"p90": 1.52, "within": False},
                "min_smooth_mm": 4.0, "applied_smooth_mm": 4.0, "removed_mm": 2.5,
                "max_height_mm": 9.0, "requested_height_mm": 10.0, "applied_scale": 1.0,
                "solves": 1, "seconds": 2.0, "smooth_seconds": 1.0, "reason": "steep"})
    out = capsys.readouterr().out
    assert "reach p90" in out and "1.52" in out and "0.31" in out
    assert "applied: smooth_mm 4 at the relief as given; it moves the surface by 2.50 mm" in out
    assert "1.52 of the most the layers can curl" in out and "do not form" in out


def test_the_curvature_program_reads_the_relief_smoothed_half_as_much_as_the_plan_did():
    """Where the plan chose a smoothing (the fit's, or the one that holds) its curvature
    program reads the input smoothed ``curvature.program_smoothing`` as much, lowered as
    the fit lowered it; where the plan chose none, or the profile asks for the target
    itself, it reads the target."""
    from types import SimpleNamespace

    from pipeline.fitting import program_relief
    from pipeline.input.simplify import simplify
    given = _hill_with_a_spike()
    opts = {"min_prominence_mm": 0.5}

    def plan(fit=None):
        return SimpleNamespace(fit=fit, validated=given)
    fitted = SimpleNamespace(local=None, applied_smooth_mm=4.0, applied_scale=1.0)
    got = program_relief(plan(fitted), opts, PROFILE)
    assert np.array_equal(got.z, simplify(given, 0.5, 2.0)[0].z, equal_nan=True)
    held = program_relief(plan(), opts, PROFILE, held_smooth_mm=6.0)
    assert np.array_equal(held.z, simplify(given, 0.5, 3.0)[0].z, equal_nan=True)
    lowered = SimpleNamespace(local=None, applied_smooth_mm=None, applied_scale=0.5)
    low = program_relief(plan(lowered), opts, PROFILE, held_smooth_mm=6.0)
    assert (np.nanmax(low.z) - np.nanmin(low.z)) == pytest.approx(
        0.5 * (np.nanmax(held.z) - np.nanmin(held.z)), rel=0.01)
    assert program_relief(plan(lowered), opts, PROFILE) is None
    assert program_relief(plan(), opts, PROFILE) is None
    whole = dataclasses.replace(PROFILE, curvature=dataclasses.replace(
        PROFILE.curvature, program_smoothing=1.0))
    assert program_relief(plan(fitted), opts, whole) is None
    # The local fit keeps what forms in the target itself.
    local = dataclasses.replace(PROFILE, flatten=dataclasses.replace(
        PROFILE.flatten, fit_smoothing="local"))
    assert program_relief(plan(), opts, local, held_smooth_mm=6.0) is None
