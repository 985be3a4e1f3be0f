"""Daemon benchmark: drop-to-first-line latency, memory, serial starvation while planning.

Runs ``hostd run`` as a real process against a simulated printer on a pty in this
process (so every executed command is time-stamped here), and prints one JSON object:

    first_line_uncached_s   drop (rename into drop/) -> first G-code command executed
    first_line_cached_s     the same file dropped again (plan from the cache)
    rss_idle_mb             daemon resident memory, idle (plan children excluded)
    rss_printing_mb         daemon resident memory while printing
    max_line_gap_planning_s largest gap between executed lines while a second job plans
    median_line_gap_s       median gap over the same window (the link's pace)

Usage: ``python benchmarks/daemon.py [--diameter-mm 15]``.
"""

import argparse
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# benchmarks/serial.py would shadow pyserial: drop this folder from the path.
sys.path[0:1] = [str(ROOT), str(ROOT / "tests")]

from daemon_helpers import DaemonProcess, jobs, write_config, write_dome  # noqa: E402
from printer_helpers import HOUSEKEEPING  # noqa: E402


class Stamper(threading.Thread):
    """Time-stamps each command the simulated firmware executes (2 ms resolution)."""

    def __init__(self, sim):
        super().__init__(daemon=True)
        self.sim = sim
        self.times = []
        self.running = True

    def run(self):
        executed = self.sim.firmware.executed
        while self.running:
            n = len(executed)
            now = time.monotonic()
            while len(self.times) < n:
                self.times.append(now)
            time.sleep(0.002)

    def first_job_line_after(self, t0):
        executed = self.sim.firmware.executed
        for i, t in enumerate(list(self.times)):
            if t >= t0 and executed[i][1].split()[0] not in HOUSEKEEPING:
                return t
        return None


def rss_mb(pid):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return None


def drop(src, drop_dir, name):
    shutil.copy(src.with_name(src.stem + ".yaml"), drop_dir / (Path(name).stem + ".yaml"))
    shutil.copy(src, drop_dir / (name + ".part"))
    t = time.monotonic()
    os.rename(drop_dir / (name + ".part"), drop_dir / name)
    return t


def wait(pred, timeout=300):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(0.05)
    raise TimeoutError


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--diameter-mm", type=float, default=15.0)
    args = ap.parse_args()
    from hostd.printer.sim import Simulator
    from hostd.printer.simconfig import SimConfig
    work = Path(tempfile.mkdtemp(prefix="hostd-bench-"))
    sim = Simulator(SimConfig(time_scale=0.0, advanced_ok=True, boot_s=0.0, baud=250000),
                    link_path=str(work / "printer"))
    port = sim.start()
    a = write_dome(work / "in" / "a.npy", diameter_mm=args.diameter_mm, height_mm=3)
    b = write_dome(work / "in2" / "b.npy", diameter_mm=args.diameter_mm + 2, height_mm=4)
    cfg = write_config(work, printers=[{"name": "p1", "profile": "generic-0.5mm", "port": port,
                                        "baud": 250000}], settle_s=0.5, poll_s=0.1)
    drop_dir = work / "share" / "drop"
    stamper = Stamper(sim)
    stamper.start()
    d = DaemonProcess(cfg)
    out = {}
    try:
        wait(lambda: sim.firmware.executed)          # connected (handshake seen)
        time.sleep(2.0)
        out["rss_idle_mb"] = round(rss_mb(d.proc.pid), 1)
        t0 = drop(a, drop_dir, "a.npy")
        t1 = wait(lambda: stamper.first_job_line_after(t0))
        out["first_line_uncached_s"] = round(t1 - t0, 3)
        out["rss_printing_mb"] = round(rss_mb(d.proc.pid), 1)
        drop(b, drop_dir, "b.npy")
        state = lambda name: {j["name"]: j["state"] for j in jobs(cfg)}.get(name)  # noqa: E731
        wait(lambda: state("b.npy") == "planning")
        w0 = time.monotonic()
        wait(lambda: state("b.npy") not in ("queued", "planning"))
        w1 = time.monotonic()
        ts = [t for t in stamper.times if w0 <= t <= w1]
        gaps = sorted(y - x for x, y in zip(ts, ts[1:]))
        out["max_line_gap_planning_s"] = round(gaps[-1], 4) if gaps else None
        out["median_line_gap_s"] = round(gaps[len(gaps) // 2], 5) if gaps else None
        out["lines_during_planning"] = len(ts)
        out["planning_window_s"] = round(w1 - w0, 2)
        wait(lambda: {j["state"] for j in jobs(cfg)} == {"done"})
        t0 = drop(a, drop_dir, "a-again.npy")
        t1 = wait(lambda: stamper.first_job_line_after(t0))
        out["first_line_cached_s"] = round(t1 - t0, 3)
        out["settle_s"], out["poll_s"] = 0.5, 0.1
        out["note"] = ("arrival by rename is complete at once when watchdog sees it; "
                       "latency includes plan, hashing, claim, link start and the start G-code "
                       "before its first command executes")
    finally:
        d.stop()
        stamper.running = False
        sim.stop()
        shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
