"""Web benchmark: requests per second, and what polling the page does to the serial stream.

Runs ``hostd run`` as a real process (web on a free loopback port) against a simulated
printer on a pty in this process, moving in real time (fast heaters, so the run is short),
and prints one JSON object:

    status_rps, page_rps          /api/status and / with 2 keep-alive clients, while printing
    status_median_ms, status_p95_ms, page_median_ms   latency while polled at 50 req/s
    baseline: max_line_gap_s, starvation_s, starvation_events   printing, nobody polling
    polled:   the same over an equal window while / and /api/status are polled at 50 req/s

Every request goes to 127.0.0.1 only; each loop is bounded in count and time.
Usage: ``python benchmarks/web.py [--window-s 10]``.
"""

import argparse
import http.client
import json
import shutil
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# benchmarks/serial.py would shadow pyserial: drop this folder from the path.
sys.path[0:1] = [str(ROOT), str(ROOT / "tests")]

from daemon_helpers import DaemonProcess, write_config, write_dome  # noqa: E402


def _daemon_bench():
    import importlib.util
    spec = importlib.util.spec_from_file_location("bench_daemon", ROOT / "benchmarks" / "daemon.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


_bd = _daemon_bench()
Stamper, drop, wait = _bd.Stamper, _bd.drop, _bd.wait


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def hammer(port, path, seconds, clients=2, max_requests=200000):
    """Requests per second for ``path`` with ``clients`` keep-alive connections."""
    count = [0] * clients
    end = time.monotonic() + seconds

    def run(i):
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        while time.monotonic() < end and count[i] < max_requests:
            conn.request("GET", path)
            r = conn.getresponse()
            r.read()
            assert r.status == 200, (path, r.status)
            count[i] += 1
        conn.close()

    t0 = time.monotonic()
    threads = [threading.Thread(target=run, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return round(sum(count) / (time.monotonic() - t0), 1)


def poll_at(port, rate_hz, seconds):
    """GET / and /api/status alternately at ``rate_hz``; returns latencies (s) per path."""
    lat = {"/": [], "/api/status": []}
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    t0 = time.monotonic()
    n = 0
    while n < rate_hz * seconds:
        due = t0 + n / rate_hz
        now = time.monotonic()
        if due > now:
            time.sleep(due - now)
        path = "/api/status" if n % 2 else "/"
        s = time.perf_counter()
        conn.request("GET", path)
        r = conn.getresponse()
        r.read()
        lat[path].append(time.perf_counter() - s)
        n += 1
    conn.close()
    return lat


def stream_window(sim, stamper, seconds, load=None):
    """Largest executed-line gap and planner starvation over ``seconds`` (optional load)."""
    st0 = dict(sim.firmware.stats)
    w0 = time.monotonic()
    result = load() if load else time.sleep(seconds)
    w1 = time.monotonic()
    st1 = dict(sim.firmware.stats)
    ts = [t for t in list(stamper.times) if w0 <= t <= w1]
    gaps = sorted(y - x for x, y in zip(ts, ts[1:]))
    return dict(window_s=round(w1 - w0, 2), lines=len(ts),
                max_line_gap_s=round(gaps[-1], 4) if gaps else None,
                median_line_gap_s=round(gaps[len(gaps) // 2], 5) if gaps else None,
                starvation_s=round(st1["starvation_s"] - st0["starvation_s"], 4),
                starvation_events=st1["starvation_events"] - st0["starvation_events"]), result


def ms(values, q):
    values = sorted(values)
    return round(1000 * values[min(len(values) - 1, int(q * len(values)))], 2)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--window-s", type=float, default=10.0)
    ap.add_argument("--diameter-mm", type=float, default=40.0)
    args = ap.parse_args()
    from hostd.printer.sim import Simulator
    from hostd.printer.simconfig import SimConfig
    work = Path(tempfile.mkdtemp(prefix="hostd-bench-web-"))
    sim = Simulator(SimConfig(time_scale=1.0, advanced_ok=True, boot_s=0.0, baud=250000,
                              hotend_tau_s=0.3, bed_tau_s=0.3), link_path=str(work / "printer"))
    link = sim.start()
    web_port = free_port()
    src = write_dome(work / "in" / "a.npy", diameter_mm=args.diameter_mm, height_mm=5)
    cfg = write_config(work, printers=[{"name": "p1", "profile": "generic-0.5mm", "port": link,
                                        "baud": 250000}], settle_s=0.5, poll_s=0.1,
                       web={"host": "127.0.0.1", "port": web_port, "token": "bench"})
    stamper = Stamper(sim)
    stamper.start()
    d = DaemonProcess(cfg)
    out = {"window_s": args.window_s, "diameter_mm": args.diameter_mm}
    try:
        wait(lambda: sim.firmware.executed, 60)
        drop(src, work / "share" / "drop", "a.npy")

        def printing():
            conn = http.client.HTTPConnection("127.0.0.1", web_port, timeout=5)
            conn.request("GET", "/api/status")
            s = json.loads(conn.getresponse().read())
            conn.close()
            job = s["printers"][0]["job"]
            return job and s["printers"][0]["state"] == "printing" and job["progress"] > 0.02
        wait(printing, 600)
        out["baseline"], _ = stream_window(sim, stamper, args.window_s)
        out["polled"], lat = stream_window(sim, stamper, args.window_s,
                                           lambda: poll_at(web_port, 50, args.window_s))
        out["status_median_ms"] = ms(lat["/api/status"], 0.5)
        out["status_p95_ms"] = ms(lat["/api/status"], 0.95)
        out["page_median_ms"] = ms(lat["/"], 0.5)
        out["status_rps"] = hammer(web_port, "/api/status", 3.0)
        out["page_rps"] = hammer(web_port, "/", 3.0)
        out["still_printing"] = bool(printing())
        out["note"] = ("printer moves in real time (time_scale 1) at 250000 baud; "
                       "rps measured while printing, 2 client threads on a 2-core machine")
    finally:
        d.stop()
        stamper.running = False
        sim.stop()
        shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
