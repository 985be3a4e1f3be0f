"""The share's G-code is for people to read: a printer runs only the G-code its node
planned and kept in its own state folder, whatever is written to the outbox or its plan
cache on the share."""

from pathlib import Path

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from hostd.kept import GCODE

EDIT = "M104 S295 ; written on the share\n"


def _printing(d):
    """Record the text of every G-code file a print starts from."""
    printing = d.lookup("printing")
    printed, real = [], printing._spool

    def spool(job, gcode):
        path = real(job, gcode)
        printed.append(Path(path).read_text())
        return path
    printing._spool = spool
    return printed


def _done(d, n):
    tick_until(d, lambda: [j["state"] for j in d.store.list()] == [J.DONE] * n,
               what="%d printed" % n)


def _bed_cleared(d):
    """A person takes the sheet off: the printer waits for that after every print."""
    d.control.clear(d.slots[0].name)


def _edit_share_copies(d, job):
    """Append the edit to every G-code of the job's plan on the share (outbox and cache)."""
    found = list(Path(job["outbox"]).glob("*.gcode")) + \
        list((Path(d.config.outbox_dir) / ".cache" / job["plan_key"]).glob("*.gcode"))
    assert found
    for path in found:
        with open(path, "a") as f:      # in place: outbox files are links into the cache
            f.write(EDIT)
    return found


def test_an_edited_cache_is_not_printed_when_the_file_is_dropped_again(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        printed = _printing(d)
        write_dome(d.config.drop_dir / "a.npy")
        _done(d, 1)
        _bed_cleared(d)
        _edit_share_copies(d, d.store.list()[0])
        write_dome(d.config.drop_dir / "a.npy")
        _done(d, 2)
        second = d.store.list()[1]
        assert "plan found in the cache" in " ".join(e["message"] or ""
                                                     for e in d.store.events(second["id"]))
        assert len(printed) == 2 and EDIT not in printed[1] and printed[1] == printed[0]
    finally:
        d.shutdown()


def test_an_edited_outbox_of_a_ready_job_is_not_printed(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        printed = _printing(d)
        d.slots[0].paused = True            # planned, then held until the edit is made
        write_dome(d.config.drop_dir / "a.npy")
        tick_until(d, lambda: [j["state"] for j in d.store.list()] == [J.READY])
        job = d.store.list()[0]
        kept = (d.config.state_dir / "plans" / job["plan_key"] / GCODE).read_text()
        _edit_share_copies(d, job)
        d.slots[0].paused = False
        _done(d, 1)
        assert printed == [kept] and EDIT not in printed[0]
    finally:
        d.shutdown()


def test_a_plan_only_the_share_holds_is_planned_again(tmp_path):
    import shutil
    d = in_process_daemon(tmp_path, 0)
    try:
        printed = _printing(d)
        write_dome(d.config.drop_dir / "a.npy")
        _done(d, 1)
        _bed_cleared(d)
        job = d.store.list()[0]
        _edit_share_copies(d, job)
        # As if another node had planned it: the share's cache has it, this node has not.
        shutil.rmtree(d.config.state_dir / "plans" / job["plan_key"])
        write_dome(d.config.drop_dir / "a.npy")
        _done(d, 2)
        second = d.store.list()[1]
        messages = " ".join(e["message"] or "" for e in d.store.events(second["id"]))
        assert "planned in" in messages and "found in the cache" not in messages
        assert EDIT not in printed[1] and printed[1] == printed[0]
    finally:
        d.shutdown()


def test_a_plan_that_cannot_be_kept_fails_its_job_not_the_node(tmp_path):
    import errno
    d = in_process_daemon(tmp_path, 0)
    try:
        def full(job_id, key):
            raise OSError(errno.ENOSPC, "No space left on device")
        d.plans.kept.keep = full
        write_dome(d.config.drop_dir / "a.npy")
        tick_until(d, lambda: [j["state"] for j in d.store.list()] == [J.FAILED])
        job = d.store.list()[0]
        assert job["error_code"] == "plan.not_kept" and "No space left" in job["error"]
        assert d.problems() == {} and not d.plans.kept.gcode(job["plan_key"])
    finally:
        d.shutdown()


def test_the_oldest_kept_plans_go_first_never_those_in_use(tmp_path):
    import os
    from hostd import kept as kept_mod
    kept = kept_mod.Kept(tmp_path)
    keys = ["k%03d" % i for i in range(kept_mod.KEEP + 5)]
    for i, key in enumerate(keys):
        (kept.staging("j" + key) / GCODE).write_text("G1 X%d\n" % i)
        kept.keep("j" + key, key)
        os.utime(kept.root / key, (1000 + i, 1000 + i))
    kept.prune(in_use={"k000"})
    left = sorted(p.name for p in kept.root.iterdir())
    assert left == ["k000"] + keys[5:]
    assert kept.gcode("k001") is None and kept.gcode("k000").read_text() == "G1 X0\n"
