"""The two outages of a printer host, ridden out: its job database full (the SD card filled
up) and its network share gone. Prints go on, systemd's watchdog is fed, nothing is lost.
Also: progress is written at a pace an SD card can take.

The daemon runs in this process and is ticked by hand. The store is made full for real,
through SQLite's page limit on the daemon's own connection, so every write fails the way
it does on a full disk ("database or disk is full"); the share goes away the way an
unmounted one does (its drop folder is no longer there).
"""

import logging
import os
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

from daemon_helpers import fill_store as fill
from daemon_helpers import Pings, in_process_daemon, make_room, ticking_daemon, write_dome
from hostd import jobs as J
from hostd import outages, watchdog
from hostd import printing as printing_mod
from hostd.errors import HostdError
from hostd.web.app import create_app


def run_until(d, predicate, timeout_s=60.0, what="condition"):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        d.tick()
        if predicate():
            return
        time.sleep(0.02)
    raise AssertionError("timed out waiting for " + what)


def test_the_store_maps_sqlite_full_to_its_own_code(tmp_path):
    store = J.JobStore(tmp_path / "jobs.sqlite")
    job_id = store.add("a.npy", "a.npy", tmp_path / "a.npy")
    fill(store)
    with pytest.raises(HostdError) as err:
        store.set_state(job_id, J.DONE, "printed")
    assert err.value.code == J.DISK_FULL
    assert "free space" in err.value.fix and str(tmp_path) in err.value.text()
    make_room(store)
    store.set_state(job_id, J.DONE, "printed")
    assert store.get(job_id)["state"] == J.DONE


def drop_dome(d, tmp_path, name):
    src = write_dome(tmp_path / "in" / name)
    for f in (src.with_suffix(".yaml"), src):
        shutil.copy(f, d.config.drop_dir / f.name)


def start_print(d, tmp_path, name="dome.npy"):
    """Drop a small dome and tick until it prints; returns its job id."""
    drop_dome(d, tmp_path, name)
    run_until(d, lambda: d.slots[0].job_id is not None, what="the print of %s to start" % name)
    return d.slots[0].job_id


@pytest.mark.slow
def test_a_full_store_keeps_the_print_going_and_records_it_once_there_is_room(
        tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(outages, "FULL_RETRY_S", 0.5)
    # Slow enough that the print is still running when the store fills.
    d = in_process_daemon(tmp_path, time_scale=0.008)
    config, pings = d.config, d.notify
    caplog.set_level(logging.INFO, logger="hostd.daemon")
    try:
        first = start_print(d, tmp_path, "first.npy")

        fill(d.store)
        drop_dome(d, tmp_path, "second.npy")
        pings_before = pings.watchdog_pings
        slot = d.slots[0]
        run_until(d, lambda: slot.link_job.snapshot()["result"] is not None, timeout_s=120,
                  what="the printer to finish")
        for _ in range(20):
            d.tick()
            time.sleep(0.05)
        # The printer finished; the store could not take it, so the slot still holds it.
        assert slot.link_job.snapshot()["result"] == "done"
        assert slot.job_id == first and d.store.get(first)["state"] == J.PRINTING
        assert "cannot record jobs" in d.problem and list(d.problems()) == ["disk_full"]
        assert [j["name"] for j in d.store.list()] == ["first.npy"]
        assert pings.watchdog_pings > pings_before, "the watchdog must be fed while printing"
        full_lines = [r for r in caplog.records if "cannot record jobs" in r.getMessage()]
        assert len(full_lines) == 1 and full_lines[0].levelno == logging.ERROR
        page = create_app(config, store=d.store, daemon=d).test_client().get("/")
        assert "cannot record jobs" in page.get_data(as_text=True)

        make_room(d.store)
        run_until(d, lambda: d.store.get(first)["state"] == J.DONE
                  and any(j["name"] == "second.npy" for j in d.store.list()),
                  what="the first job recorded done and the second file taken")
        assert slot.job_id != first and d.problem is None
        done = Path(d.store.get(first)["input_path"])
        assert done.name == "first.npy" and done.is_file() and config.done_dir in done.parents
        assert "takes writes again" in caplog.text
    finally:
        d.shutdown()


@pytest.mark.slow
def test_progress_is_written_every_few_seconds_not_every_tick(tmp_path):
    d = in_process_daemon(tmp_path, time_scale=0.012)   # a print of 5-7 s
    writes = []
    update = d.store.update

    def counted(job_id, event=None, **values):
        if "progress" in values and event is None:
            writes.append(time.monotonic())
        return update(job_id, event, **values)
    d.store.update = counted
    try:
        drop_dome(d, tmp_path, "dome.npy")
        run_until(d, lambda: d.slots[0].job_id is not None, what="the print to start")
        job_id, started = d.slots[0].job_id, time.monotonic()
        run_until(d, lambda: d.store.get(job_id)["state"] == J.DONE, timeout_s=120,
                  what="the print to end")
        seconds = time.monotonic() - started
        assert seconds > 2 * printing_mod.PROGRESS_S, "the print must outlast a few writes"
        assert 2 <= len(writes) <= seconds / printing_mod.PROGRESS_S + 2, (len(writes), seconds)
        assert min(b - a for a, b in zip(writes, writes[1:])) >= 0.9 * printing_mod.PROGRESS_S
    finally:
        d.shutdown()


@pytest.mark.slow
def test_a_lost_share_keeps_the_print_going_and_is_not_recreated_on_the_local_disk(
        tmp_path, caplog):
    d = in_process_daemon(tmp_path, time_scale=0.008)
    caplog.set_level(logging.INFO, logger="hostd.daemon")
    drop = d.config.drop_dir
    try:
        job_id, slot = start_print(d, tmp_path), d.slots[0]
        assert d.status()["printers"][0]["job_name"] == "dome.npy"   # for the farm view

        drop.rename(drop.with_name("drop.away"))     # the share's drop folder is gone
        pings = d.notify.watchdog_pings
        run_until(d, lambda: d.problem is not None, what="the lost share to be noticed")
        deadline = time.monotonic() + 4 * d.config.heartbeat_s
        while time.monotonic() < deadline:
            d.tick()
            time.sleep(0.02)
        assert not drop.exists(), "the drop folder must not be recreated on the local disk"
        assert "cannot write to the share" in d.problem and list(d.problems()) == ["share"]
        assert d.notify.watchdog_pings >= pings + 2, "the watchdog must be fed while printing"
        assert slot.job_id == job_id and slot.link_job.snapshot()["result"] in (None, "done")
        lost = [r for r in caplog.records if "cannot write to the share" in r.getMessage()]
        assert len(lost) == 1 and lost[0].levelno == logging.ERROR

        drop.with_name("drop.away").rename(drop)
        run_until(d, lambda: d.store.get(job_id)["state"] == J.DONE, timeout_s=120,
                  what="the print to end and be filed")
        assert d.problem is None and "share takes writes again" in caplog.text
        done = Path(d.store.get(job_id)["input_path"])
        assert done.is_file() and d.config.done_dir in done.parents
    finally:
        d.shutdown()


@pytest.mark.slow
def test_prints_are_fed_from_a_local_copy_of_the_gcode(tmp_path):
    """The outbox is often on the share: a print reads a copy in ``state_dir/spool``,
    which goes when the print ends (and, left by a crash, when the daemon starts)."""
    stale = tmp_path / "state" / "spool" / "left-by-a-crash.gcode"
    stale.parent.mkdir(parents=True)
    stale.write_text("G28\n")
    d = in_process_daemon(tmp_path, time_scale=0.003)
    try:
        assert not stale.exists()
        job_id, slot = start_print(d, tmp_path), d.slots[0]
        source = Path(slot.link_job.snapshot()["name"])
        assert source.parent == d.config.spool_dir
        outbox = next(Path(d.store.get(job_id)["outbox"]).glob("*.gcode"))
        assert source.read_bytes() == outbox.read_bytes()
        run_until(d, lambda: d.store.get(job_id)["state"] == J.DONE, timeout_s=120,
                  what="the print to end")
        assert not source.exists()
    finally:
        d.shutdown()


@pytest.mark.slow
def test_a_share_folder_that_stays_unwritable_is_told_once_not_at_every_heartbeat(
        tmp_path, caplog):
    """The lease renews but done/ takes no file (its permissions, a full quota, here a
    file in its place): the outage lasts until done/ takes a write, told once; it used
    to end and start again at every heartbeat, two log lines each time."""
    d = in_process_daemon(tmp_path, time_scale=0.002)
    caplog.set_level(logging.INFO, logger="hostd.daemon")
    done = d.config.done_dir
    try:
        job_id = start_print(d, tmp_path)
        shutil.rmtree(done)
        done.write_text("not a folder\n")
        run_until(d, lambda: d.problem is not None, timeout_s=120,
                  what="the print to end and done/ to refuse it")
        assert str(done) in d.problem
        deadline = time.monotonic() + 5 * d.config.heartbeat_s
        while time.monotonic() < deadline:
            d.tick()
            assert d.problem is not None, "the outage must last while done/ takes nothing"
            time.sleep(0.02)
        told = [r for r in caplog.records if "cannot write to the share" in r.getMessage()]
        assert len(told) == 1 and "takes writes again" not in caplog.text
        assert d.store.get(job_id)["state"] == J.PRINTING   # not recorded before it is filed

        done.unlink()
        done.mkdir()
        run_until(d, lambda: d.store.get(job_id)["state"] == J.DONE, what="the print filed")
        assert d.problem is None and caplog.text.count("share takes writes again") == 1
        assert done in Path(d.store.get(job_id)["input_path"]).parents
    finally:
        d.shutdown()


@pytest.mark.slow
def test_a_loop_stuck_on_a_share_that_does_not_answer_ends_no_print(
        tmp_path, monkeypatch, caplog):
    """An NFS server rebooting blocks every call on its share, and the run loop makes
    such calls. systemd's watchdog is fed while a print runs (a restart would end it
    and bring no share back) or its end is not yet recorded, not when nothing prints;
    the stuck loop is told once, with where, and is the node's problem until it moves
    again."""
    monkeypatch.setattr(watchdog, "STALL_S", 1.0)
    caplog.set_level(logging.INFO, logger="hostd.daemon")
    gate, armed = threading.Event(), threading.Event()

    def wait_for(predicate, what, timeout_s=60.0):
        deadline = time.monotonic() + timeout_s
        while not predicate():
            assert time.monotonic() < deadline, "timed out waiting for " + what
            time.sleep(0.05)

    with ticking_daemon(tmp_path, time_scale=0.01) as d:
        publish = d.farm.publish_status

        def hanging_publish(status):  # the share's status folder, not answering
            if armed.is_set():
                gate.wait(60)
            return publish(status)

        d.farm.publish_status = hanging_publish
        try:
            store = J.JobStore(d.config.db_path)
            drop_dome(d, tmp_path, "dome.npy")
            wait_for(lambda: d.slots[0].job_id is not None, "the print to start")
            job_id, link = d.slots[0].job_id, d.slots[0].link_job
            armed.set()
            wait_for(lambda: d.problem is not None, "the stuck loop to be noticed", 10)
            assert "not completed a round" in d.problem and "_heartbeat" in d.problem, d.problem
            assert list(d.problems()) == ["stuck"]
            pings = d.notify.watchdog_pings
            time.sleep(1.5)
            assert d.notify.watchdog_pings >= pings + 3, "fed while the print runs"
            assert link.snapshot()["result"] is None and link.snapshot()["confirmed"] > 0
            stuck = [r for r in caplog.records if "not completed a round" in r.getMessage()]
            assert len(stuck) == 1 and stuck[0].levelno == logging.ERROR
            # The print ends while the loop is stuck: its outcome is not recorded yet, and a
            # restart would leave it "interrupted", so systemd still hears that hostd lives.
            wait_for(lambda: link.snapshot()["result"] is not None, "the print to end", 120)
            pings = d.notify.watchdog_pings
            time.sleep(1.0)
            assert d.notify.watchdog_pings >= pings + 2, "fed until the print's end is recorded"
            assert store.get(job_id)["state"] == J.PRINTING

            armed.clear()
            gate.set()
            wait_for(lambda: d.problem is None, "the loop to move again", 10)
            assert "moves again" in caplog.text
            wait_for(lambda: store.get(job_id)["state"] == J.DONE, "the print to be filed", 120)

            gate.clear()
            armed.set()                   # stuck again, with nothing printing
            wait_for(lambda: d.problem is not None, "the second stall", 10)
            pings = d.notify.watchdog_pings
            time.sleep(1.0)
            assert d.notify.watchdog_pings == pings, "not fed: a restart costs no print"
        finally:
            armed.clear()
            gate.set()


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def test_the_watchdog_is_fed_while_the_loop_moves_or_a_print_runs(caplog):
    caplog.set_level(logging.INFO, logger="hostd.daemon")
    clock, printing = Clock(), [False]
    pings = Pings()
    watch = watchdog.LoopWatch(pings, lambda: printing[0], 1.0, clock=clock)
    watch.check()
    assert pings.watchdog_pings == 1 and watch.problem is None
    clock.now += watchdog.STALL_S + 1            # no round completed since
    watch.check()
    assert pings.watchdog_pings == 1, "stuck, nothing printing: left to systemd"
    assert "not completed a round" in watch.problem
    printing[0] = True
    watch.check()
    watch.check()
    assert pings.watchdog_pings == 3, "stuck while printing: a restart would end the print"
    assert caplog.text.count("not completed a round") == 1
    watch.tick()
    watch.check()
    assert pings.watchdog_pings == 4 and watch.problem is None and "moves again" in caplog.text


def test_a_round_that_fails_does_not_count_as_one(tmp_path, monkeypatch):
    """A round ending in an error leaves the watchdog's clock where it was, so a loop
    failing at every round is seen like a stuck one (and restarted if nothing prints)."""
    d = in_process_daemon(tmp_path, time_scale=0)
    try:
        d.tick()
        done = d.watch.last_tick
        monkeypatch.setattr(d.printing, "follow", lambda: 1 / 0)
        with pytest.raises(ZeroDivisionError):
            d.tick()
        assert d.watch.last_tick == done
        monkeypatch.undo()
        d.tick()
        assert d.watch.last_tick > done
    finally:
        d.shutdown()


@pytest.mark.slow
def test_after_a_damaged_job_database_the_claimed_files_wait_for_a_person(tmp_path):
    """A power cut damaged the job database: the daemon starts anyway on a new one, the
    files it had claimed are queued again, and no printer starts one before a person
    has resumed it (which one was printing is not known any more)."""
    from test_jobs import damage
    d = in_process_daemon(tmp_path, time_scale=0, settle_s=0.0)
    drop_dome(d, tmp_path, "dome.npy")
    run_until(d, lambda: d.store.list(), what="the file to be claimed")
    db = d.config.db_path
    d.shutdown()
    damage(db)

    d = in_process_daemon(tmp_path, time_scale=0, settle_s=0.0)
    try:
        [job] = d.store.list()
        assert job["rel_path"] == "dome.npy" and job["state"] == J.QUEUED
        assert all(s.paused for s in d.slots) and "job database was damaged" in d.problem
        assert list(d.problems()) == ["damaged"]
        assert list(db.parent.glob("jobs.sqlite.damaged-*"))
        run_until(d, lambda: d.store.get(job["id"])["state"] == J.READY, what="the plan")
        for _ in range(20):
            d.tick()
        assert d.slots[0].job_id is None, "held: nothing starts before a person resumes"
        d.control.resume("p1")
        assert d.problem is None
        run_until(d, lambda: d.store.get(job["id"])["state"] == J.DONE, what="the print")
    finally:
        d.shutdown()


@pytest.mark.slow
def test_a_second_hostd_with_the_same_node_id_refuses_to_start(tmp_path):
    """A cloned SD card: both nodes are "raspberrypi". The one started second sees the
    lease renewed by the other and exits with what to change, before it claims or adopts
    anything of the other's."""
    share = tmp_path / "share"
    with ticking_daemon(tmp_path / "a", time_scale=0, share=share, node_id="raspberrypi"):
        with pytest.raises(HostdError) as err:
            in_process_daemon(tmp_path / "b", time_scale=0, share=share, node_id="raspberrypi")
        assert err.value.code == "config.node_id" and err.value.key == "node_id"
        pid_host = "hostd pid %d on host %s" % (os.getpid(), socket.gethostname())
        assert pid_host in err.value.text() and "cloned SD card" in err.value.text()
    # Stopped cleanly, the first one's lease is released: the node starts at once.
    started = time.monotonic()
    d = in_process_daemon(tmp_path / "b", time_scale=0, share=share, node_id="raspberrypi")
    d.shutdown()
    assert time.monotonic() - started < 5


def test_while_another_hostd_writes_the_lease_nothing_is_taken(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="hostd.daemon")
    d = in_process_daemon(tmp_path, time_scale=0)
    try:
        d.outages.twin_seen("0123abcd raspberrypi 4242", time.monotonic())
        assert "another hostd uses node_id 'n1' on this share: hostd pid 4242 on host " \
            "raspberrypi" in d.problem and list(d.problems()) == ["node_id"]
        drop_dome(d, tmp_path, "dome.npy")
        for _ in range(40):
            d.tick()
            time.sleep(0.02)
        assert d.store.list() == [], "nothing claimed while a twin writes the lease"
        d.outages.twin_seen(None, time.monotonic() + d.config.lease_s + 1)
        assert d.problem is None and "carrying on" in caplog.text
        run_until(d, lambda: d.store.list(), what="the file to be claimed")
    finally:
        d.shutdown()


def test_requeue_takes_the_sidecar_a_person_wrote_beside_a_failed_file(tmp_path):
    """A failed plan is mostly fixed in the sidecar (smooth_mm, size_mm): NAME.error.txt
    says to write one beside the file in failed/ and requeue, and the requeue takes it
    along, also for a file that came without one."""
    d = in_process_daemon(tmp_path, time_scale=0)
    try:
        (d.config.drop_dir / "broken.png").write_bytes(b"this is not a picture")
        deadline = time.monotonic() + 20
        while not [j for j in d.store.list() if j["state"] == J.FAILED]:
            assert time.monotonic() < deadline
            d.tick()
            time.sleep(0.05)
        [job] = d.store.list()
        assert job["sidecar_path"] is None
        failed = d.config.failed_dir
        told = (failed / "broken.error.txt").read_text()
        assert "sidecar (same name, .yaml; write one if there is none)" in told
        assert "hostd requeue %s" % job["id"] in told
        (failed / "broken.yaml").write_text("smooth_mm: 3\n")
        cli = J.JobStore(d.config.db_path)
        req = cli.request("requeue", job["id"])
        while cli.wait_answer(req, timeout_s=0.01) is None:
            assert time.monotonic() < deadline
            d.tick()
        side = Path(d.store.get(job["id"])["sidecar_path"])
        assert side.read_text() == "smooth_mm: 3\n" and side.parent != failed
        assert not (failed / "broken.yaml").exists()
    finally:
        d.shutdown()
