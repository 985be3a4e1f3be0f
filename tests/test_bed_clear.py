"""After every print, finished or not, a printer waits until a person says its bed is clear:
the part (or what is left of it) is on the bed, and the next job must not start on top of it.
A profile that takes the finished part off by itself (``bed_clear: auto`` with
``gcode.clear_bed``) goes on at once."""

import time
from pathlib import Path

import pytest

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from hostd.web.view import NodeView

ROOT = Path(__file__).resolve().parents[1]


def _state(d, name):
    return {j["name"]: j["state"] for j in d.store.list()}.get(name)


def _job(d, name):
    return next(j for j in d.store.list() if j["name"] == name)


def _ticks(d, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        d.tick()
        time.sleep(0.02)


def _ask(d, action, target):
    """A request as the terminal commands and the page write it; the loop's answer."""
    req = d.store.request(action, target)
    for _ in range(200):
        d.tick()
        answer = d.store.wait_answer(req, timeout_s=0.05, poll_s=0.01)
        if answer is not None:
            return answer
    raise AssertionError("no answer to %s %s" % (action, target))


def test_a_finished_print_holds_its_printer_until_a_person_says_the_bed_is_clear(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        write_dome(d.config.drop_dir / "first.npy")
        tick_until(d, lambda: _state(d, "first.npy") == J.DONE, what="the first print")
        write_dome(d.config.drop_dir / "second.npy")
        tick_until(d, lambda: _state(d, "second.npy") == J.READY, what="the second plan")
        _ticks(d, 2.0)
        assert _state(d, "second.npy") == J.READY, "started on top of the finished sheet"
        slot = d.slots[0]
        assert "first.npy finished" in slot.held and not slot.paused
        assert "hostd clear p1" in d.store.printers()["p1"]["held"]
        card = NodeView(d.config, d, db_path=d.config.db_path).printers()[0]
        assert card["waiting_for_person"] is True and "first.npy" in card["held"]
        assert _ask(d, "clear", "p1") == (True, "bed of p1 is clear: it takes the next job")
        tick_until(d, lambda: _state(d, "second.npy") == J.DONE, what="the second print")
        assert "second.npy finished" in d.slots[0].held
    finally:
        d.shutdown()


def test_a_cancelled_print_holds_its_printer_and_a_requeue_does_not_reprint_it(tmp_path):
    """Cancel the printing job with another queued: nothing starts on the cancelled print,
    and the cancelled job requeued at once (its plan cached, ready at once) waits too."""
    d = in_process_daemon(tmp_path, 0.1, sim="hotend_tau_s=1&bed_tau_s=1")
    try:
        write_dome(d.config.drop_dir / "first.npy")
        write_dome(d.config.drop_dir / "second.npy")
        tick_until(d, lambda: J.PRINTING in (_state(d, "first.npy"), _state(d, "second.npy")),
                   what="a print to start")
        printing = next(j for j in d.store.list() if j["state"] == J.PRINTING)
        other = next(j for j in d.store.list() if j["id"] != printing["id"])
        ok, text = _ask(d, "cancel", printing["id"])
        assert ok, text
        tick_until(d, lambda: d.store.get(printing["id"])["state"] == J.CANCELLED,
                   what="the cancel recorded")
        assert "cancelled" in d.slots[0].held
        assert _ask(d, "requeue", printing["id"])[0]
        tick_until(d, lambda: d.store.get(printing["id"])["state"] == J.READY
                   and d.store.get(other["id"])["state"] == J.READY, what="both ready")
        _ticks(d, 2.0)
        assert d.slots[0].job_id is None, "a job started on top of the cancelled print"
        assert {d.store.get(i)["state"] for i in (printing["id"], other["id"])} == {J.READY}
        assert _ask(d, "clear", "p1")[0]
        tick_until(d, lambda: d.slots[0].job_id is not None, what="a print after the clear")
    finally:
        d.shutdown()


def test_the_wait_outlives_a_restart(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        write_dome(d.config.drop_dir / "first.npy")
        tick_until(d, lambda: _state(d, "first.npy") == J.DONE, what="the first print")
    finally:
        d.shutdown()
    d = in_process_daemon(tmp_path, 0)     # a power cut or a restart: the sheet is still there
    try:
        assert "first.npy finished" in d.slots[0].held and not d.slots[0].paused
        write_dome(d.config.drop_dir / "second.npy")
        tick_until(d, lambda: _state(d, "second.npy") == J.READY, what="the second plan")
        _ticks(d, 1.0)
        assert _state(d, "second.npy") == J.READY
        assert _ask(d, "clear", "p1")[0]
        tick_until(d, lambda: _state(d, "second.npy") == J.DONE, what="the second print")
    finally:
        d.shutdown()


def test_clear_is_refused_while_the_printer_prints_and_harmless_when_nothing_waits(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        assert _ask(d, "clear", "p1") == (True, "p1 does not wait for its bed to be cleared")
        from hostd.errors import HostdError
        d.slots[0].job_id = "j1"     # as while a print runs
        try:
            with pytest.raises(HostdError) as err:
                d.control.clear("p1")
        finally:
            d.slots[0].job_id = None
        assert err.value.code == "control.printing" and "printing j1" in err.value.text()
        ok, text = _ask(d, "clear", "nope")
        assert not ok and "no printer 'nope'" in text
    finally:
        d.shutdown()


def _auto_profile(folder, clear_bed):
    text = (ROOT / "profiles" / "generic-0.5mm.yaml").read_text()
    text = text.replace("name: generic-0.5mm", "name: belt-0.5mm").replace(
        "bed_clear: person", "bed_clear: auto")
    if clear_bed is not None:
        text = text.replace("gcode:\n", "gcode:\n  clear_bed: |\n%s" % "".join(
            "    %s\n" % line for line in clear_bed.splitlines()), 1)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "belt-0.5mm.yaml").write_text(text)
    return folder / "belt-0.5mm.yaml"


def test_a_profile_that_clears_its_bed_goes_on_at_once(tmp_path, monkeypatch):
    from daemon_helpers import gcode_commands
    profiles = tmp_path / "profiles"
    _auto_profile(profiles, "; run the belt one bed length\nG1 Y500 F3000\nM84")
    monkeypatch.setenv("HOSTD_PROFILES", str(profiles))
    d = in_process_daemon(tmp_path, 0, profile="belt-0.5mm")
    try:
        write_dome(d.config.drop_dir / "first.npy")
        write_dome(d.config.drop_dir / "second.npy")
        tick_until(d, lambda: {_state(d, "first.npy"), _state(d, "second.npy")} == {J.DONE},
                   what="both prints, one after the other")
        assert d.slots[0].held is None
        gcode = d.printing.gcode(_job(d, "first.npy"))
        # the profile's end, then its clear_bed
        assert gcode_commands(gcode)[-3:] == ["M84", "G1 Y500 F3000", "M84"]
    finally:
        d.shutdown()


def test_a_plan_without_the_clear_gcode_waits_even_on_an_auto_profile(tmp_path, monkeypatch):
    """A plan made before its profile said ``auto`` (ready, not planned again) does not
    take its part off: its printer waits for a person."""
    profiles = tmp_path / "profiles"
    _auto_profile(profiles, "G1 Y500 F3000")
    monkeypatch.setenv("HOSTD_PROFILES", str(profiles))
    d = in_process_daemon(tmp_path, 0, profile="belt-0.5mm")
    try:
        write_dome(d.config.drop_dir / "first.npy")
        tick_until(d, lambda: _state(d, "first.npy") == J.DONE, what="the print")
        assert d.slots[0].held is None
        gcode = d.printing.gcode(_job(d, "first.npy"))
        text = gcode.read_text()
        gcode.write_text(text[:text.index("; hostd clear_bed")] + "; end of hostd job\n")
        assert not d.printing._clears_bed(d.slots[0], gcode)
    finally:
        d.shutdown()


@pytest.mark.parametrize("clear_bed", [None, "; only a comment\n\n"])
def test_auto_without_clear_gcode_is_a_profile_error(tmp_path, clear_bed):
    from pipeline.errors import InvalidProfile
    from pipeline.profiles.profile import load_profile
    path = _auto_profile(tmp_path, clear_bed)
    with pytest.raises(InvalidProfile) as err:
        load_profile(path)
    assert err.value.code == "profile.bed_clear" and "gcode.clear_bed" in err.value.text()


def test_a_web_cancel_of_a_printing_job_answers_that_it_worked(tmp_path, monkeypatch):
    """The page cancels the printer itself, then asks the run loop to record it; a loop
    busy for a moment finds the print already ended by that cancel. The answer is that
    the cancel worked (it did), not an internal error; then the printer waits, and the
    API's clear releases it."""
    from daemon_helpers import ticking_daemon
    from hostd.web.app import create_app
    auth = {"Authorization": "Bearer s3cret-token"}
    with ticking_daemon(tmp_path, 0.1, sim="hotend_tau_s=1&bed_tau_s=1",
                        token="s3cret-token") as d:
        client = create_app(d.config, store=d.store, daemon=d).test_client()
        reader = J.JobStore(d.config.db_path, create=False)
        write_dome(d.config.drop_dir / "first.npy")
        deadline = time.monotonic() + 120
        while not reader.list(J.PRINTING):
            assert time.monotonic() < deadline, "no print started"
            time.sleep(0.05)
        [job] = reader.list(J.PRINTING)
        real = d.control.answer

        def busy_round():
            time.sleep(1.0)      # a slow round of the loop: the printer's cancel ends meanwhile
            real()
        monkeypatch.setattr(d.control, "answer", busy_round)
        r = client.post("/api/jobs/%s/cancel" % job["id"], headers=auth)
        assert r.status_code == 200 and r.json["ok"] is True, r.json
        monkeypatch.undo()
        while reader.get(job["id"])["state"] != J.CANCELLED:
            assert time.monotonic() < deadline, "the cancel was not recorded"
            time.sleep(0.05)
        status = client.get("/api/status").json
        assert status["waiting_for_person"] == ["p1"]
        assert "first.npy was cancelled" in status["printers"][0]["held"]
        r = client.post("/api/printers/p1/clear", headers=auth)
        assert r.status_code == 200 and r.json["result"].startswith("bed of p1 is clear"), r.json
        assert client.get("/api/status").json["waiting_for_person"] == []
        reader.close()


def _failed_job(d):
    (d.config.drop_dir / "broken.png").write_bytes(b"this is not a picture")
    tick_until(d, lambda: d.store.list(J.FAILED), what="the junk to fail")
    return d.store.list(J.FAILED)[0]


def test_a_refused_requeue_is_a_refusal_told_by_the_dropped_names(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        job = _failed_job(d)
        (d.config.failed_dir / "broken.yaml").write_text("smooth_mm: [1, 2]\n")
        ok, text = _ask(d, "requeue", job["id"])
        assert not ok and text.startswith("not requeued: ")
        assert "broken.yaml" in text and str(tmp_path) not in text, text
        assert d.store.get(job["id"])["state"] == J.FAILED
        assert (d.config.failed_dir / "broken.png").exists()
    finally:
        d.shutdown()


def test_a_requeue_does_not_follow_a_symlinked_sidecar(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        job = _failed_job(d)
        secret = tmp_path / "secret.yaml"
        secret.write_text("smooth_mm: 2\n")
        side = d.config.failed_dir / "broken.yaml"
        side.symlink_to(secret)
        ok, text = _ask(d, "requeue", job["id"])
        assert not ok and "failed/broken.yaml" in text and "not a regular file" in text, text
        assert str(tmp_path) not in text
        assert side.is_symlink() and (d.config.failed_dir / "broken.png").exists()
        assert d.store.get(job["id"])["state"] == J.FAILED
        assert not list(d.farm.claim_dir.rglob("broken*"))
    finally:
        d.shutdown()
