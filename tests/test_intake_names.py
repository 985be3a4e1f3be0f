"""Names a drop folder can hold but a database or page cannot (bytes that are not UTF-8),
and one file's failure at intake, never block the other files of a scan or the page."""

import errno
import os

import pytest

from daemon_helpers import fill_store, in_process_daemon, make_room, tick_until, write_dome
from hostd.web.app import create_app


def _bytes_path(folder, name):
    return os.fsencode(str(folder)) + b"/" + name


def test_a_name_that_is_not_utf8_is_taken_under_a_safe_name(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        drop = d.config.drop_dir
        write_dome(drop / "good.npy")
        with open(drop / "good.npy", "rb") as f:
            data = f.read()
        with open(_bytes_path(drop, b"top\xffbad.npy"), "wb") as f:
            f.write(data)
        (drop / "elsewhere").mkdir()          # a folder of no printer here: left in place
        with open(_bytes_path(drop / "elsewhere", b"bad\xff\xfename.npy"), "wb") as f:
            f.write(data)
        client = create_app(d.config, d.store, d).test_client()
        tick_until(d, lambda: len(d.store.list()) == 2)
        names = sorted(j["name"] for j in d.store.list())
        assert names == ["good.npy", "top_bad.npy"]
        assert [j["rel_path"] for j in d.store.list() if j["name"] == "top_bad.npy"] \
            == ["top\ufffdbad.npy"]
        page = client.get("/")
        assert page.status_code == 200
        assert "bad\ufffd\ufffdname.npy" in page.get_data(as_text=True)
    finally:
        d.shutdown()


def test_one_files_failure_at_intake_leaves_the_others_taken(tmp_path, monkeypatch):
    d = in_process_daemon(tmp_path, 0)
    try:
        drop = d.config.drop_dir
        write_dome(drop / "a.npy")
        write_dome(drop / "b.npy")
        real = d.intake.take

        def faulty(cand):
            if cand.path.name == "a.npy":
                raise RuntimeError("a fault of this file alone")
            return real(cand)
        monkeypatch.setattr(d.intake, "take", faulty)
        tick_until(d, lambda: len(d.store.list()) == 1)
        assert [j["name"] for j in d.store.list()] == ["b.npy"]
    finally:
        d.shutdown()


def test_junk_is_refused_as_it_is_taken_without_a_plan(tmp_path, monkeypatch):
    from hostd import jobs as J
    from hostd import plans as plans_mod
    started = []
    real = plans_mod.PlanProcess

    def counting(job_id, *args, **kw):
        started.append(job_id)
        return real(job_id, *args, **kw)
    monkeypatch.setattr(plans_mod, "PlanProcess", counting)
    d = in_process_daemon(tmp_path, 0)
    try:
        drop = d.config.drop_dir
        for i in range(30):
            (drop / ("junk-%02d.npy" % i)).write_bytes(b"GIF89a not an array %d" % i)
        write_dome(drop / "good.npy")
        tick_until(d, lambda: len(d.store.list()) == 31 and all(
            j["state"] != J.QUEUED for j in d.store.list()))
        jobs = {j["name"]: j for j in d.store.list()}
        junk = [j for n, j in jobs.items() if n.startswith("junk")]
        assert all(j["state"] == J.FAILED and j["error_code"] == "heightfield.content_mismatch"
                   for j in junk)
        assert started == [jobs["good.npy"]["id"]]
    finally:
        d.shutdown()


def test_a_file_that_cannot_be_recorded_goes_to_failed_with_the_reason(tmp_path, monkeypatch):
    d = in_process_daemon(tmp_path, 0)
    try:
        drop = d.config.drop_dir
        write_dome(drop / "a.npy")
        write_dome(drop / "b.npy")
        real = d.store.add

        def faulty(name, *args, **kw):
            if name == "a.npy":
                raise ValueError("a fault of this file alone")
            return real(name, *args, **kw)
        monkeypatch.setattr(d.store, "add", faulty)
        failed = d.config.failed_dir
        tick_until(d, lambda: (failed / "a.error.txt").exists() and len(d.store.list()) == 1)
        assert [j["name"] for j in d.store.list()] == ["b.npy"]
        assert (failed / "a.npy").is_file() and (failed / "a.yaml").is_file()
        text = (failed / "a.error.txt").read_text()
        assert "ValueError: a fault of this file alone" in text and "back into the drop" in text
        assert not list(d.farm.claim_dir.glob("*/a.*"))
    finally:
        d.shutdown()


def test_a_full_job_database_at_intake_waits_for_room_and_loses_no_file(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        fill_store(d.store)
        write_dome(d.config.drop_dir / "a.npy")
        tick_until(d, lambda: "disk_full" in d.problems())
        assert list(d.problems()) == ["disk_full"] and d.store.list() == []
        make_room(d.store)
        tick_until(d, lambda: len(d.store.list()) == 1)
        assert [j["name"] for j in d.store.list()] == ["a.npy"]
    finally:
        d.shutdown()


def test_a_share_failing_at_a_claim_leaves_every_file_of_the_scan_for_later(tmp_path, monkeypatch):
    d = in_process_daemon(tmp_path, 0)
    try:
        drop = d.config.drop_dir
        write_dome(drop / "a.npy")
        write_dome(drop / "b.npy")
        real, failures = d.farm.claim, []

        def flaky(cand):
            if not failures:
                failures.append(cand.path.name)
                raise OSError(errno.EIO, "Input/output error", str(cand.path))
            return real(cand)
        monkeypatch.setattr(d.farm, "claim", flaky)
        tick_until(d, lambda: failures and len(d.store.list()) == 2)
        assert failures and sorted(j["name"] for j in d.store.list()) == ["a.npy", "b.npy"]
        assert d.problems() == {}
    finally:
        d.shutdown()


@pytest.mark.parametrize("module, unreadable, code", [
    ("pipeline.input.sidecar", "a.yaml", "sidecar.unreadable"),
    ("pipeline.input.heightfield", "a.npy", "heightfield.unreadable")])
def test_a_file_that_cannot_be_read_fails_itself_not_the_node(tmp_path, monkeypatch, module,
                                                               unreadable, code):
    import importlib
    real = open

    def guarded(path, *args, **kw):
        if os.path.basename(path) == unreadable:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real(path, *args, **kw)
    monkeypatch.setattr(importlib.import_module(module), "open", guarded, raising=False)
    d = in_process_daemon(tmp_path, 0)
    try:
        write_dome(d.config.drop_dir / "a.npy")
        write_dome(d.config.drop_dir / "b.npy")
        tick_until(d, lambda: len(d.store.list()) == 2 and (d.config.failed_dir / "a.npy").exists())
        states = {j["name"]: (j["state"], j["error_code"]) for j in d.store.list()}
        assert states["a.npy"] == ("failed", code)
        assert states["b.npy"][0] != "failed" and d.problems() == {}
    finally:
        d.shutdown()


def test_junk_under_a_name_that_is_not_utf8_is_refused_under_its_safe_name(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        (d.config.drop_dir / "p1").mkdir()       # the printer's own folder: taken here
        with open(_bytes_path(d.config.drop_dir / "p1", b"bad\xff\xfename.npy"), "wb") as f:
            f.write(b"junk junk\n" * 40)
        client = create_app(d.config, d.store, d).test_client()
        d.tick()
        assert client.get("/").status_code == 200
        assert client.get("/api/status").status_code == 200
        error = d.config.failed_dir / "bad_name.error.txt"
        tick_until(d, error.exists)
        text = error.read_text(encoding="utf-8")
        assert "p1/bad\ufffd\ufffdname.npy" in text and "not .npy data" in text
        assert (d.config.failed_dir / "bad_name.npy").is_file()
        [job] = d.store.list()
        assert job["error_code"] == "heightfield.content_mismatch"
        assert client.get("/api/jobs").status_code == 200 and client.get("/").status_code == 200
    finally:
        d.shutdown()
