"""The drop-folder watcher (scan alone, settle rule, names) and farm claims."""

import os
import time

import pytest

from hostd.farm import Farm, PlanCache, archive_done, archive_failed, plan_key
from hostd.watcher import Candidate, Watcher, ignored, name_problem, safe_stem


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def test_ignored_names():
    for name in (".hidden.png", "a.png.part", "a.tmp", "a.png.crdownload", "~$a.png",
                 ".~lock.a.png#", "a.png~"):
        assert ignored(name), name
    assert not ignored("dome.png")


def test_settle_rule_with_scan_alone(tmp_path):
    clock = Clock()
    w = Watcher(tmp_path, settle_s=2.0, poll_s=0.5, clock=clock)
    f = tmp_path / "dome.npy"
    f.write_bytes(b"x" * 10)
    assert w.poll() == []                       # just seen
    clock.t += 1.0
    with open(f, "ab") as h:                    # still growing
        h.write(b"y" * 10)
    os.utime(f, ns=(time.time_ns(), time.time_ns() + 10**9))
    assert w.poll() == []
    clock.t += 1.5
    assert w.poll() == []                       # changed 1.5 s ago
    clock.t += 1.0
    [c] = w.poll()
    assert c.rel_path == "dome.npy" and c.target is None and c.sidecar is None
    clock.t += 1.0
    assert w.poll() == []                       # reported once


def test_rename_arrival_is_complete_at_once(tmp_path):
    clock = Clock()
    w = Watcher(tmp_path, settle_s=100.0, poll_s=0.5, clock=clock)
    (tmp_path / "a.png").write_bytes(b"x")
    w.renamed.add(str(tmp_path / "a.png"))
    [c] = w.poll()
    assert c.rel_path == "a.png"


def test_sidecar_waited_for_subfolders_symlinks(tmp_path):
    clock = Clock()
    w = Watcher(tmp_path, settle_s=1.0, poll_s=0.1, clock=clock)
    (tmp_path / "mk3").mkdir()
    (tmp_path / "mk3" / "a.png").write_bytes(b"x")
    (tmp_path / "b.npy").write_bytes(b"x")
    (tmp_path / ".claimed").mkdir()
    (tmp_path / ".claimed" / "c.png").write_bytes(b"x")
    (tmp_path / "notes.txt").write_text("x")
    outside = tmp_path.parent / ("outside-%s.png" % tmp_path.name)
    outside.write_bytes(b"x")
    (tmp_path / "link.png").symlink_to(outside)
    w.poll()
    clock.t += 0.5
    (tmp_path / "b.yaml").write_text("pixel_mm: 1\n")   # sidecar arrives late
    w.poll()
    clock.t += 0.6
    got = {c.rel_path: c for c in w.poll()}
    assert set(got) == {"mk3/a.png"}                     # b waits for its sidecar
    assert got["mk3/a.png"].target == "mk3"
    clock.t += 0.5
    [b] = w.poll()
    assert b.rel_path == "b.npy" and b.sidecar == tmp_path / "b.yaml"


def test_untrusted_names():
    assert name_problem("dome.png") is None
    assert name_problem("a" * 300 + ".png")
    assert name_problem("a\nb.png")
    assert safe_stem("../../etc/passwd") == "passwd"
    assert safe_stem("My dome (v2) ; rm -rf.png") == "My_dome_v2_rm_-rf"
    assert safe_stem("∆∆∆.png") == "input"


def _cand(drop, rel, target=None):
    path = drop / rel
    side = path.with_name(path.stem + ".yaml")
    return Candidate(path, rel, target, side if side.exists() else None)


def test_claim_exactly_once_and_release_of_dead_node(tmp_path):
    drop = tmp_path / "drop"
    (drop / "mk3").mkdir(parents=True)
    (drop / "mk3" / "a b.png").write_bytes(b"x")
    (drop / "mk3" / "a b.yaml").write_text("copies: 2\n")
    a, b = Farm(drop, "a", lease_s=5), Farm(drop, "b", lease_s=5)
    a.setup()
    b.setup()
    cand = _cand(drop, "mk3/a b.png", "mk3")
    got = a.claim(cand)
    assert b.claim(cand) is None
    path, side = got
    assert path == drop / ".claimed" / "a" / "mk3" / "a_b.png" and side.read_text() == "copies: 2\n"
    assert not (drop / "mk3" / "a b.png").exists()
    assert b.release_dead() == 0                 # a's lease is fresh
    os.utime(drop / ".claimed" / "a" / ".lease", (time.time() - 10,) * 2)
    assert b.release_dead() == 2
    assert (drop / "mk3" / "a_b.png").exists() and (drop / "mk3" / "a_b.yaml").exists()


@pytest.mark.parametrize("skew_s", [3600.0, -3600.0])
def test_ages_on_the_share_are_read_on_the_shares_clock(tmp_path, monkeypatch, skew_s):
    """A node whose own clock is an hour off (a Pi without a clock battery, before NTP)
    neither releases a live node's claims nor takes a dead node for alive."""
    drop = tmp_path / "drop"
    a, b = Farm(drop, "a", lease_s=5), Farm(drop, "b", lease_s=5)
    a.setup()
    (drop / "x.png").write_bytes(b"x")
    a.claim(_cand(drop, "x.png"))
    a.publish_status({"state": "running", "printers": []})
    real = time.time
    monkeypatch.setattr(time, "time", lambda: real() + skew_s)
    b.setup()                  # renews b's lease: the share's "now"
    assert b.release_dead() == 0 and b.live_peers() == ["a"]
    assert (drop / ".claimed" / "a" / "@" / "x.png").exists()

    # a stops: its lease and status are not written again for 10 s of the share's time
    for f in (drop / ".claimed" / "a" / ".lease", drop / ".hostd" / "nodes" / "a.json"):
        os.utime(f, (real() - 10,) * 2)
    b.renew_lease()
    assert b.live_peers() == [] and b.release_dead() == 1
    assert (drop / "x.png").exists()


def test_status_file_archives_and_cache(tmp_path):
    drop = tmp_path / "drop"
    farm = Farm(drop, "n1")
    farm.setup()
    farm.publish_status({"printers": [], "queue_length": 3})
    status, age_s = farm.nodes()["n1"]
    assert status["queue_length"] == 3 and status["last_seen"] > 0 and abs(age_s) < 5
    src = tmp_path / "x.png"
    src.write_bytes(b"1")
    dest, side = archive_failed(src, None, tmp_path / "failed", "x.png", "it is broken")
    assert dest.read_bytes() == b"1" and (tmp_path / "failed" / "x.error.txt").read_text() \
        == "it is broken\n"
    src.write_bytes(b"2")
    dest2, _ = archive_done(src, None, tmp_path / "done", "x.png")
    assert dest2.parent.name == time.strftime("%Y-%m-%d") and dest2.read_bytes() == b"2"
    assert plan_key("h", None, "p", "1") != plan_key("h", None, "p", "2")
    cache = PlanCache(tmp_path / "cache")
    tmp = cache.staging("job1")
    (tmp / "dome.gcode").write_text("G28\n")
    cache.store(tmp, "k", "dome")
    gcode = cache.export("k", tmp_path / "out", "other")
    assert gcode.name == "other.gcode" and gcode.read_text() == "G28\n"


def test_watchdog_shutdown_race_is_not_reported_as_an_error(tmp_path, caplog):
    """watchdog logs an ERROR when a file changes in the instant its observer stops;
    the watcher drops that one record (the next start rescans) and nothing else."""
    import logging
    w = Watcher(tmp_path / "drop", poll_s=0.1)
    w.start()
    w.stop()
    inotify_log = logging.getLogger("watchdog.observers.inotify")
    with caplog.at_level(logging.ERROR, logger="watchdog.observers.inotify"):
        inotify_log.error("InotifyEmitter.queue_events() called when the thread is inactive")
        inotify_log.error("inotify watch limit reached")
    assert [r.getMessage() for r in caplog.records] == ["inotify watch limit reached"]


def test_a_second_hostd_with_the_same_node_id_is_seen_by_the_lease(tmp_path):
    """Two nodes set up from one cloned SD card keep its hostname, the default node_id:
    each renewal says who else wrote the lease, and a start watches a lease that was
    not released."""
    import threading
    drop = tmp_path / "drop"
    a, b = Farm(drop, "pi"), Farm(drop, "pi")
    a.setup()
    assert a.renew_lease() is None                 # only its own writes so far
    b.setup()
    assert a.renew_lease() == b.holder and b.renew_lease() == a.holder

    stop = threading.Event()

    def renewing():
        while not stop.wait(0.1):
            a.renew_lease()

    t = threading.Thread(target=renewing)
    t.start()
    try:
        assert Farm(drop, "pi").held_by_another(1.0) == a.holder
    finally:
        stop.set()
        t.join()
    started = time.monotonic()
    assert Farm(drop, "pi").held_by_another(0.5) is None        # a crashed: not renewed
    assert time.monotonic() - started >= 0.5
    a.renew_lease("stopped")
    started = time.monotonic()
    assert Farm(drop, "pi").held_by_another(5.0) is None        # released: no wait
    assert time.monotonic() - started < 1.0
    assert b.renew_lease() is None                              # a stopped is no twin


def test_inputs_sharing_a_stem_never_share_their_error_or_sidecar(tmp_path):
    drop, failed = tmp_path / "drop", tmp_path / "failed"
    drop.mkdir()
    for name in ("empty.npy", "empty.png", "empty.yaml"):
        (drop / name).write_text(name)
    a, a_side = archive_failed(drop / "empty.npy", drop / "empty.yaml", failed, "empty.npy",
                               "the array is empty")
    b, b_side = archive_failed(drop / "empty.png", None, failed, "empty.png",
                               "the picture is empty")
    assert (a.name, a_side.name, b.name, b_side) == ("empty.npy", "empty.yaml", "empty-2.png",
                                                     None)
    assert (failed / "empty.error.txt").read_text() == "the array is empty\n"
    assert (failed / "empty-2.error.txt").read_text() == "the picture is empty\n"
    # A requeue looks for STEM.yaml beside the input: the png has none of its own.
    assert not b.with_name(b.stem + ".yaml").exists()
