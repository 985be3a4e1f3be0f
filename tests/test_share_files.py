"""Nothing on the share that is not a regular file is opened, and no read there is
unbounded: a FIFO planted as a node status file, a claimed input or sidecar swapped for
one, or a link to /dev/zero, never freezes the run loop or a terminal command."""

import contextlib
import os
import subprocess
import sys
import threading

import pytest

from daemon_helpers import ROOT, in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from hostd.errors import HostdError
from hostd.farm import Farm


def _unblock(fifos):
    """Let a reader stuck in an open of these FIFOs go (a test that fails must end)."""
    for fifo in fifos:
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            os.close(fd)
        except OSError:
            pass


@contextlib.contextmanager
def unblocked_after(fifos, timeout=20):
    """Runs the block; if it is still running after ``timeout``, a reader stuck on these
    FIFOs is let go (again and again) and the test fails once the block ends."""
    done, fired = threading.Event(), []

    def watch():
        if not done.wait(timeout):
            fired.append(True)
            while not done.wait(0.1):
                _unblock(fifos)
    t = threading.Thread(target=watch, daemon=True)
    t.start()
    try:
        yield
    finally:
        done.set()
        t.join()
    assert not fired, "blocked on a FIFO for more than %d s" % timeout


def finishes(fn, fifos, timeout=20):
    with unblocked_after(fifos, timeout):
        return fn()


def test_a_fifo_among_the_node_status_files_is_skipped(tmp_path):
    farm = Farm(tmp_path / "drop", "n1")
    farm.setup()
    farm.publish_status({"state": "running", "printers": []})
    fifo = farm.nodes_dir / "evil.json"
    os.mkfifo(fifo)
    (farm.nodes_dir / "elsewhere.json").symlink_to(farm.nodes_dir / "n1.json")
    nodes = finishes(farm.nodes, [fifo])
    assert sorted(nodes) == ["n1"]


def test_a_fifo_in_place_of_the_lease_reads_as_no_lease(tmp_path):
    farm = Farm(tmp_path / "drop", "n1")
    farm.setup()
    lease = farm.claim_dir / ".lease"
    lease.unlink()
    os.mkfifo(lease)
    assert finishes(farm.lease_holder, [lease]) == (None, None)


def test_a_daemon_with_a_fifo_status_file_keeps_its_loop_and_takes_files(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    fifo = d.farm.nodes_dir / "evil.json"
    os.mkfifo(fifo)
    try:
        write_dome(d.config.drop_dir / "a.npy")

        with unblocked_after([fifo], timeout=90):
            tick_until(d, lambda: [j["state"] for j in d.store.list()] == [J.DONE],
                       timeout=60, what="the dropped file printed")
    finally:
        _unblock([fifo])
        d.shutdown()


@pytest.mark.parametrize("swapped", ["input", "sidecar"])
def test_a_claimed_file_swapped_for_a_fifo_fails_its_job_not_the_loop(tmp_path, swapped):
    d = in_process_daemon(tmp_path, 0)
    fifos = []
    try:
        d.plans.start = lambda: None          # queued, not planned yet: then swap it
        write_dome(d.config.drop_dir / "a.npy")
        tick_until(d, lambda: len(d.store.list()) == 1)
        job = d.store.list()[0]
        path = job["input_path"] if swapped == "input" else job["sidecar_path"]
        os.unlink(path)
        os.mkfifo(path)
        fifos.append(path)
        del d.plans.start

        with unblocked_after(fifos, timeout=30):
            tick_until(d, lambda: d.store.get(job["id"])["state"] == J.FAILED, timeout=30,
                       what="the job failed")
        failed = d.store.get(job["id"])
        assert failed["error_code"] == "job.unreadable"
        assert "not a regular file" in failed["error"]
    finally:
        _unblock(fifos)
        d.shutdown()


def test_the_share_helper_refuses_special_files_and_bounds_reads(tmp_path):
    from hostd import share
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    (tmp_path / "zero").symlink_to("/dev/zero")
    (tmp_path / "big").write_bytes(b"x" * 2000)
    for name in ("fifo", "zero"):
        with pytest.raises(HostdError) as err:
            finishes(lambda: share.read_bytes(tmp_path / name), [fifo])
        assert err.value.code == share.NOT_REGULAR and share.refused(err.value)
    with pytest.raises(HostdError) as err:
        share.read_bytes(tmp_path / "big", limit=1000)
    assert err.value.code == share.TOO_LARGE and "1000" in str(err.value)
    assert share.read_bytes(tmp_path / "big", limit=2000) == b"x" * 2000


@pytest.mark.parametrize("planted", ["fifo", "zero"])
def test_a_runtime_file_that_is_a_fifo_or_dev_zero_does_not_hang_hostd_jobs(tmp_path, planted):
    run_dir = tmp_path / "run"
    (run_dir / "hostd").mkdir(parents=True)
    pointer = run_dir / "hostd" / "daemon.json"
    if planted == "fifo":
        os.mkfifo(pointer)
    else:
        pointer.symlink_to("/dev/zero")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = dict(os.environ, XDG_RUNTIME_DIR=str(run_dir), PYTHONPATH=str(ROOT))
    # Run under a wrapper that reports its child's peak memory; capped, since a read of
    # /dev/zero to its end would take all the memory there is.
    wrapper = ("import resource, subprocess, sys\n"
               "cap = lambda: resource.setrlimit(resource.RLIMIT_AS, (1 << 31, 1 << 31))\n"
               "r = subprocess.run([sys.executable, '-m', 'hostd', 'jobs'], preexec_fn=cap,\n"
               "                   capture_output=True, text=True, timeout=25)\n"
               "sys.stderr.write(r.stderr)\n"
               "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
               "sys.exit(r.returncode)\n")
    try:
        r = subprocess.run([sys.executable, "-c", wrapper], cwd=elsewhere, env=env,
                           capture_output=True, text=True, timeout=30)
    finally:
        _unblock([pointer])
    assert r.returncode != 0 and "no hostd daemon found" in r.stderr, r.stderr[-2000:]
    peak_mb = int(r.stdout.split()[-1]) / 1024
    assert peak_mb < 400, "hostd jobs peaked at %.0f MB" % peak_mb


def test_a_fifo_where_the_plan_writes_its_result_is_not_waited_for(tmp_path):
    from hostd.planning import _read_result
    fifo = tmp_path / "result.json"
    os.mkfifo(fifo)
    assert finishes(lambda: _read_result(fifo), [fifo]) is None


def test_a_daemon_process_with_a_fifo_status_file_stops_at_once_on_sigterm(tmp_path):
    import signal
    import time
    from daemon_helpers import daemon, jobs, wait_for, write_config
    config = write_config(tmp_path)
    nodes = tmp_path / "share" / "drop" / ".hostd" / "nodes"
    nodes.mkdir(parents=True)
    fifo = nodes / "evil.json"
    os.mkfifo(fifo)
    write_dome(tmp_path / "share" / "drop" / "a.npy")
    try:
        with daemon(config, env={"XDG_RUNTIME_DIR": str(tmp_path / "run")}) as d:
            # Taking the file needs the loop to go round after a heartbeat read the FIFO.
            wait_for(lambda: jobs(config), timeout=60, what="the file taken", proc=d)
            t = time.monotonic()
            d.proc.send_signal(signal.SIGTERM)
            assert d.proc.wait(20) == 0
            assert time.monotonic() - t < 15
    finally:
        _unblock([fifo])
