"""Helpers for the daemon end-to-end tests: inputs, configs, daemon processes, simulators."""

import contextlib
import dataclasses
import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from hostd import daemon as daemon_mod
from hostd.config import load_config

ROOT = Path(__file__).resolve().parents[1]
FAST_SIM = dict(time_scale=0.0, advanced_ok=True, boot_s=0.0, baud=2000000)
# The simulated printer of the daemon tests that only wait for a print to end: nothing takes
# time but the wire, modelled at ten times a fast serial link (the host's configured baud is
# untouched). A 15 mm dome's 5600 lines then print about a second sooner than at 2 Mbaud
# (2.2 s instead of 3.3 on average here) with 15-30 % less CPU, simulator and link together.
# Tests that act while a print runs slow it (time_scale) or set their own.
SIM = "sim://?time_scale=0&advanced_ok=1&boot_s=0&baud=20000000"


def write_dome(path, diameter_mm=15, height_mm=3):
    """A small dome ``.npy`` (heights in mm) with its ``pixel_mm`` sidecar; returns the path.

    The sidecar names the paper's method: it plans in a fifth of a second, and the thin
    shell the free method is checked by holds a dome this small and this curved for a
    person (a 1.5 mm sheet hardly bends to an 11 mm radius)."""
    from pipeline.input import shapes
    hf = shapes.dome(diameter_mm=diameter_mm, height_mm=height_mm)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The sidecar first: written into a drop folder, the input must not settle without it.
    path.with_name(path.stem + ".yaml").write_text("pixel_mm: %r\nmethod: isoline\n"
                                                    % float(hf.pixel_mm))
    np.save(path, hf.z)
    return path


def write_config(folder, node_id="n1", printers=None, share=None, **extra):
    """A hostd.yaml in ``folder``; the share (drop/outbox/done/failed) may be shared.

    A file written into the drop folder is taken 0.2-0.25 s after its last write (settle_s,
    scanned every poll_s): most tests wait for that once or more."""
    folder = Path(folder)
    share = Path(share or folder / "share")
    data = dict(node_id=node_id, drop_dir=str(share / "drop"), state_dir=str(folder / "state"),
                outbox_dir=str(share / "outbox"), done_dir=str(share / "done"),
                failed_dir=str(share / "failed"), settle_s=0.2, poll_s=0.05, heartbeat_s=0.5,
                lease_s=30.0, stop_timeout_s=10.0,
                printers=printers or [{"name": "p1", "profile": "generic-0.5mm",
                                       "port": SIM,
                                       "baud": 2000000}],
                # Any free port: several test daemons run at once.
                web={"host": "127.0.0.1", "port": 0, "token": None})
    data.update(extra)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "hostd.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def belt_profile(folder, name="belt-0.5mm"):
    """A profile like generic-0.5mm for a printer that takes the finished part off its bed
    by itself (``bed_clear: auto``): prints follow each other without a person. Written into
    ``folder``; returns the environment that makes hostd find it (``HOSTD_PROFILES``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    text = (ROOT / "profiles" / "generic-0.5mm.yaml").read_text()
    text = text.replace("name: generic-0.5mm", "name: " + name).replace(
        "bed_clear: person", "bed_clear: auto").replace(
        "gcode:\n", "gcode:\n  clear_bed: |\n    G1 Y{bed_y_mm} F3000 ; the belt carries the part off\n", 1)
    (folder / (name + ".yaml")).write_text(text)
    return {"HOSTD_PROFILES": str(folder)}


def hostd(*args, timeout=60, **kw):
    return subprocess.run([sys.executable, "-m", "hostd", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout, **kw)


class DaemonProcess:
    """``hostd run -c CONFIG`` as a real process; its output goes to ``log``."""

    def __init__(self, config, env=None):
        self.config = Path(config)
        self.log = self.config.with_name("daemon-%d.log" % time.monotonic_ns())
        self._out = open(self.log, "w")
        # A process group of its own, as a terminal's foreground job is (see ctrl_c).
        self.proc = subprocess.Popen([sys.executable, "-m", "hostd", "run", "-c", str(config)],
                                     cwd=ROOT, stdout=self._out, stderr=subprocess.STDOUT,
                                     env=dict(os.environ, **(env or {})),
                                     start_new_session=True)

    def stop(self, sig=signal.SIGTERM, timeout=30):
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout)
        finally:
            self._out.close()

    def ctrl_c(self):
        """What Ctrl-C in its terminal does: SIGINT to every process of its group."""
        os.killpg(self.proc.pid, signal.SIGINT)

    def output(self):
        return self.log.read_text()


@contextlib.contextmanager
def daemon(config, env=None):
    d = DaemonProcess(config, env)
    try:
        yield d
    finally:
        if d.proc.poll() is None:
            d.stop(signal.SIGKILL)
        else:
            d._out.close()


def jobs(config):
    """Stored jobs as dicts, read from the daemon's store in this process (read-only; works
    with or without a daemon). Polling through ``hostd jobs --json`` cost a Python start-up
    per poll, about a core's worth while two daemons printed; :func:`cli_jobs` is that command."""
    from hostd.errors import HostdError
    from hostd.jobs import JobStore
    try:
        store = JobStore(_db_path(config), create=False)
    except HostdError as exc:
        assert exc.code == "jobs.missing", exc
        return []    # the daemon has not created its store yet
    try:
        return store.list()
    finally:
        store.close()


_DB_PATHS = {}


def _db_path(config):
    """The job store's path in ``config``, read again only when the file changed (the tests
    poll :func:`jobs` every 0.05 s; parsing the YAML was most of a poll)."""
    key = (str(config), os.stat(config).st_mtime_ns)
    if key not in _DB_PATHS:
        _DB_PATHS[key] = load_config(config).db_path
    return _DB_PATHS[key]


def cli_jobs(config):
    """``hostd jobs --json``: the same rows as :func:`jobs`, through the command."""
    r = hostd("jobs", "--json", "-c", config)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def wait_for(predicate, timeout=60, what="condition", proc=None, every=0.05):
    """Polls ``predicate`` every ``every`` s (a read of the job store costs ~1 ms: the wait
    that ends a step is not what the tests measure) until it holds; fails after ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        if proc is not None and proc.proc.poll() is not None:
            raise AssertionError("daemon exited (%s) waiting for %s:\n%s"
                                 % (proc.proc.returncode, what, proc.output()[-3000:]))
        time.sleep(every)
    raise AssertionError("timed out waiting for %s%s" % (
        what, ("\n" + proc.output()[-3000:]) if proc else ""))


def states(config):
    return {j["name"]: j["state"] for j in jobs(config)}


def gcode_commands(path):
    from hostd.printer.protocol import clean
    with open(path) as f:
        return [c for c in (clean(line) for line in f) if c]


def all_files(folder):
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob("*") if p.is_file())


def fill_store(store):
    """Pin a job store's database at its size and use up the room left in the pages of the
    tables that grow (events, control requests: the filler requests are answered ones)."""
    pages = store.db.execute("PRAGMA page_count").fetchone()[0]
    store.db.execute("PRAGMA max_page_count = %d" % pages)
    for sql in ("INSERT INTO events (job_id, at, kind, message) VALUES ('filler', 0, 'filler', ?)",
                "INSERT INTO control (at, action, target, done_at, ok, result) "
                "VALUES (0, 'filler', '', 0, 1, ?)"):
        for size in (4000, 1000, 200, 50, 10, 1):
            try:
                while True:
                    store.db.execute(sql, ("x" * size,))
            except sqlite3.OperationalError as exc:
                assert "full" in str(exc)


def make_room(store):
    store.db.execute("PRAGMA max_page_count = 1073741823")


class Pings:
    """A notifier that counts watchdog pings."""

    watchdog_s = None
    enabled = True

    def __init__(self):
        self.watchdog_pings = 0

    def watchdog(self):
        self.watchdog_pings += 1

    def ready(self, *a):
        pass

    status = stopping = ready


def in_process_daemon(tmp_path, time_scale, sim="", profile="generic-0.5mm", baud=2000000,
                      token=None, port=None, **extra):
    """A daemon in this process with one simulated printer ``p1`` (no web server), set up.

    ``sim``: more ``sim://`` options (``"fault_reset_line=200"``); ``baud``: what the host
    believes the printer's link runs at; ``port``: a port instead of ``sim://`` (a
    :func:`pty_simulator`'s, whose executed commands the test reads)."""
    port = port or ((SIM if not time_scale else
                     "sim://?time_scale=%g&advanced_ok=1&boot_s=0" % time_scale)
                    + ("&" + sim if sim else ""))
    printers = [{"name": "p1", "profile": profile, "baud": baud, "port": port}]
    config = load_config(write_config(tmp_path, printers=printers, heartbeat_s=0.2, **extra))
    config = dataclasses.replace(config, web=dataclasses.replace(config.web, port=None,
                                                                 token=token))
    d = daemon_mod.Daemon(config, notifier=Pings())
    d.setup()
    return d


def tick_until(d, predicate, timeout=60, what="condition"):
    """Run the daemon's loop until ``predicate()`` holds; fails the test after ``timeout``."""
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out waiting for " + what
        d.tick()
        time.sleep(0.02)


@contextlib.contextmanager
def ticking_daemon(tmp_path, time_scale, **extra):
    """:func:`in_process_daemon` with its loop ticking on a thread of its own (which owns
    the daemon and its store, as the run loop does) until the block ends; yields it."""
    stop, ready, held = threading.Event(), threading.Event(), {}

    def loop():
        try:
            d = held["d"] = in_process_daemon(tmp_path, time_scale, **extra)
        finally:
            ready.set()
        try:
            while not stop.is_set():
                d.tick()
                time.sleep(0.02)
        finally:
            d.shutdown()

    runner = threading.Thread(target=loop)
    runner.start()
    try:
        assert ready.wait(30) and "d" in held, "the daemon did not set up"
        yield held["d"]
    finally:
        stop.set()
        runner.join(30)


def drop(src, drop_dir, name):
    """Copy ``src`` (and sidecar) into the drop folder the way a careful client does."""
    drop_dir.mkdir(parents=True, exist_ok=True)
    side = src.with_name(src.stem + ".yaml")
    if side.exists():
        shutil.copy(side, drop_dir / (Path(name).stem + ".yaml"))
    shutil.copy(src, drop_dir / (name + ".part"))
    os.rename(drop_dir / (name + ".part"), drop_dir / name)


@contextlib.contextmanager
def pty_simulator(**options):
    """A simulator on a real pty in this process (its executed commands are readable):
    yields (simulator, port path). ``options``: SimConfig fields over the fast defaults."""
    from hostd.printer.sim import Simulator
    from hostd.printer.simconfig import SimConfig
    folder = tempfile.mkdtemp(prefix="hostd-e2e-")
    sim = Simulator(SimConfig(**dict(FAST_SIM, **options)), link_path=os.path.join(folder, "printer"))
    path = sim.start()
    try:
        yield sim, path
    finally:
        sim.stop()
        shutil.rmtree(folder, ignore_errors=True)
