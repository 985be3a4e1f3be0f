"""A plan prints by itself only within its profile's printable limits; outside them it is
held at ready until a person approves it ("Print anyway", ``hostd approve``)."""

import time
from pathlib import Path

import pytest

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from hostd.web.app import create_app, problem_sentence
from pipeline import printable
from pipeline.plan import plan_file
from pipeline.profiles.profile import load_profile
from pipeline.profiles.schema import PrintableLimits

ROOT = Path(__file__).resolve().parents[1]


def _report(invalid_area=0.0, displacement=0.0, coverage=1.0):
    return {"flatten": {"invalid_area_fraction": invalid_area},
            "simulation": {"mean_displacement_fraction": displacement},
            "toolpath": {"coverage": coverage},
            "heightfield": {"longest_diameter_mm": 170.0}}


def test_each_limit_holds_a_plan_outside_it_and_says_what_and_how():
    limits = PrintableLimits(max_invalid_area=0.25, max_mean_displacement=0.03, min_coverage=0.9)
    section, problems = printable.gate(_report(), limits)
    assert problems == [] and section["outside"] == []
    section, problems = printable.gate(_report(0.36, 0.033, 0.89), limits, name="tile")
    assert section["outside"] == list(printable.CODES)
    assert section["figures"] == {"invalid_area": 0.36, "mean_displacement": 0.033,
                                  "coverage": 0.89}
    text = " ".join(p["message"] for p in problems)
    assert "36 %" in text and "5.6 mm" in text and "89 %" in text
    assert all("tile." in p["fix"] for p in problems)


def test_a_warning_reads_as_a_sentence_without_markdown():
    said = problem_sentence({"code": "x", "message": "the layout folds (3 triangles)",
                             "fix": "raise smooth_mm, e.g. `smooth_mm: 3`"})
    assert said == "The layout folds (3 triangles). Fix: Raise smooth_mm, e.g. smooth_mm: 3."


def _strict_profile(folder):
    """generic-0.5mm asking for full coverage: no plan meets it."""
    text = (ROOT / "profiles" / "generic-0.5mm.yaml").read_text()
    text = text.replace("name: generic-0.5mm", "name: strict-0.5mm")
    text = text.replace("min_coverage: 0.90", "min_coverage: 1.0")
    assert "strict-0.5mm" in text and "min_coverage: 1.0" in text
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "strict-0.5mm.yaml").write_text(text)


def test_a_plan_outside_the_limits_is_planned_but_not_printable(tmp_path, monkeypatch):
    _strict_profile(tmp_path / "profiles")
    monkeypatch.setenv("HOSTD_PROFILES", str(tmp_path / "profiles"))
    path = write_dome(tmp_path / "dome.npy")
    plan = plan_file(path, load_profile("strict-0.5mm"))
    r = plan.report
    assert not plan.blocked and plan.needs_decision and not r["printable"]
    assert r["needs_decision"] and r["gate"]["outside"] == ["printable.coverage"]
    assert "printable.coverage" in [w["code"] for w in r["warnings"]]
    loose = plan_file(path, load_profile("generic-0.5mm"))
    assert loose.printable and loose.report["gate"]["outside"] == []
    from hostd.planner import preview_title
    assert "isoline method" in preview_title(loose)


def test_the_daemon_holds_it_at_ready_until_a_person_approves(tmp_path, monkeypatch):
    _strict_profile(tmp_path / "profiles")
    monkeypatch.setenv("HOSTD_PROFILES", str(tmp_path / "profiles"))
    d = in_process_daemon(tmp_path, 0, profile="strict-0.5mm", token="secret")
    try:
        write_dome(d.config.drop_dir / "dome.npy")
        job = lambda: (d.store.list() or [{}])[0]           # noqa: E731
        tick_until(d, lambda: job().get("state") == J.READY, what="the plan")
        t = time.monotonic()
        while time.monotonic() - t < 2.0:                   # an idle printer, yet it waits
            d.tick()
            time.sleep(0.02)
        assert job()["state"] == J.READY and "tool paths cover" in job()["decision"]
        client = create_app(d.config, d.store, d).test_client()
        page = client.get("/jobs/%s" % job()["id"]).get_data(as_text=True)
        assert "Print anyway" in page and "Waits for you" in page and "{&#39;code" not in page
        assert "Layout method</dt><dd>isoline" in page
        assert "Print anyway" in client.get("/").get_data(as_text=True)
        assert d.control.approve(job()["id"]).startswith("approved")
        assert job()["decision"] is None
        tick_until(d, lambda: job()["state"] in (J.PRINTING, J.DONE), what="the print")
        with pytest.raises(Exception, match="does not wait"):
            d.control.approve(job()["id"])
    finally:
        d.shutdown()


def test_the_decision_names_what_would_print_it():
    from hostd.reports import decision
    report = {"needs_decision": True, "gate": {"outside": ["printable.displacement"]},
              "warnings": [
                  {"code": "printable.displacement", "message": "the sheet ends 4 % off",
                   "fix": "a smoother relief departs less"},
                  {"code": "plan.other_method", "message": "the free layout method does "
                   "not form it either", "fix": "lower or smooth the relief"},
                  {"code": "plan.hold", "message": "smoothed to 6 mm the sheet holds",
                   "fix": "write `smooth_mm: 6` in x.yaml"},
                  {"code": "fit.lowered", "message": "lowered", "fix": "nothing to do"}]}
    said = decision(report)
    assert said.startswith("Outside the profile's printable limits: the sheet ends 4 % off.")
    assert ("Instead: the free layout method does not form it either: lower or smooth the "
            "relief. Smoothed to 6 mm the sheet holds: write `smooth_mm: 6` in x.yaml." in said)
    assert "lowered" not in said
