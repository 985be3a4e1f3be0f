"""Web benchmark: requests per second, and what polling the page does to the serial stream.

Runs ``hostd run`` as a real process (web on a free loopback port) against a simulated
printer on a pty in this process, moving in real time (fast heaters, so the run is short),
and prints one JSON object:

    status_rps, page_rps          /api/status and / with 2 keep-alive clients, while printing
    status_median_ms, status_p95_ms, page_median_ms   latency while polled at 50 req/s
    baseline: max_line_gap_s, starvation_s, starvation_events   printing, nobody polling
    polled:   the same over an equal window while / and /api/status are polled at 50 req/s

With ``--pollers N`` instead: serial lines/s of a real-time print with nobody polling and
with N clients polling /api/status (``--poll-hz`` each, from a process of their own), on a
``sim://`` printer (the simulator beside the link) and on ``hostd sim-printer`` behind a pty
(a printer of its own, like a real one); with the daemon's and the pollers' CPU seconds.

With ``--slow-heads N``: N connections each send one header line every ``--every-s`` (and
reopen when closed) while /healthz, the page and the emergency stop are probed once a second.

Every request goes to 127.0.0.1 only; each loop is bounded in count and time.
Usage: ``python benchmarks/web.py [--window-s 10] [--pollers 200 | --slow-heads 600]``.
"""

import argparse
import http.client
import json
import shutil
import socket
import subprocess
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


def _load(name):
    import importlib.util
    spec = importlib.util.spec_from_file_location("bench_" + name, ROOT / "benchmarks" / (name + ".py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


_bd = _daemon_bench()
Stamper, drop, wait = _bd.Stamper, _bd.drop, _bd.wait
web_load = _load("web_load")


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


def printing_daemon(work, port, baud, diameter_mm, web_port):
    """``hostd run`` printing a dome on ``port``; returns it once the print is under way."""
    src = write_dome(work / "in" / "a.npy", diameter_mm=diameter_mm, height_mm=5)
    cfg = write_config(work, printers=[{"name": "p1", "profile": "generic-0.5mm", "port": port,
                                        "baud": baud}], settle_s=0.5, poll_s=0.1,
                       web={"host": "127.0.0.1", "port": web_port, "token": "bench"})
    d = DaemonProcess(cfg)
    wait(lambda: _answers(web_port), 60)
    drop(src, work / "share" / "drop", "a.npy")

    def printing():
        p = web_load.status(web_port)["printers"][0]
        return p["job"] and p["state"] == "printing" and p["job"]["progress"] > 0.02
    wait(printing, 600)
    return d


def _answers(port):
    try:
        web_load.status(port, timeout=2)
        return True
    except (OSError, ValueError):
        return False


def pollers_main(args):
    """Lines/s with 0 and ``args.pollers`` pollers, on sim:// and on a pty printer."""
    opts = dict(web_load.SIM_OPTIONS, time_scale=args.time_scale)
    out = {"pollers": args.pollers, "poll_hz": args.poll_hz, "window_s": args.window_s,
           "time_scale": args.time_scale,
           "diameter_mm": args.diameter_mm, "loadavg_before": open("/proc/loadavg").read().split()[:3]}
    for kind in ("sim", "pty"):
        work = Path(tempfile.mkdtemp(prefix="hostd-bench-poll-"))
        sim = None
        if kind == "sim":
            port = "sim://?baud=250000&" + "&".join("%s=%s" % kv for kv in opts.items())
        else:
            port = str(work / "printer")
            flags = [a for k, v in opts.items() for a in ("--" + k.replace("_", "-"), str(v))]
            sim = subprocess.Popen([sys.executable, "-m", "hostd", "sim-printer", "--baud",
                                    "250000", "--link", port, *flags], cwd=ROOT,
                                   stdout=subprocess.PIPE, text=True)
            sim.stdout.readline()
        web_port = free_port()
        d = printing_daemon(work, port, 250000, args.diameter_mm, web_port)
        try:
            pid = d.proc.pid
            c0 = web_load.cpu_s(pid)
            idle = web_load.stream_rate(web_port, args.window_s)
            c1 = web_load.cpu_s(pid)
            polled = web_load.stream_rate(web_port, args.window_s, args.pollers, args.poll_hz)
            c2 = web_load.cpu_s(pid)
            # Idle again: the print's own pace changes along it (short moves, long ones).
            after = web_load.stream_rate(web_port, args.window_s)
            idle["daemon_cpu_s"], polled["daemon_cpu_s"] = round(c1 - c0, 2), round(c2 - c1, 2)
            out[kind] = {"idle": idle, "polled": polled, "idle_after": after,
                         "polled_vs_idle": round(polled["lines_per_s"] / max(
                             1e-9, (idle["lines_per_s"] + after["lines_per_s"]) / 2), 3),
                         "link_in_child_process": bool(web_load.child_pids(pid))}
        finally:
            d.stop()
            if sim is not None:
                sim.terminate()
                sim.wait(10)
            shutil.rmtree(work, ignore_errors=True)
    out["loadavg_after"] = open("/proc/loadavg").read().split()[:3]
    out["note"] = ("simulated printer at 250000 baud, moves at time_scale; lines/s from the "
                   "link's lines_sent; pollers in a process of their own; 2-core machine")
    print(json.dumps(out))


def slow_heads_main(args):
    work = Path(tempfile.mkdtemp(prefix="hostd-bench-heads-"))
    web_port = free_port()
    cfg = write_config(work, printers=[{"name": "p1", "profile": "generic-0.5mm",
                                        "port": "sim://?time_scale=0&boot_s=0"}],
                       web={"host": "127.0.0.1", "port": web_port, "token": "bench"})
    d = DaemonProcess(cfg)
    try:
        wait(lambda: _answers(web_port), 60)
        out = {"loadavg_before": open("/proc/loadavg").read().split()[:3]}
        out.update(web_load.slow_heads(web_port, "bench", args.slow_heads, args.every_s,
                                       int(args.window_s)))
        out["loadavg_after"] = open("/proc/loadavg").read().split()[:3]
    finally:
        d.stop()
        shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(out))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--window-s", type=float, default=10.0)
    ap.add_argument("--diameter-mm", type=float, default=40.0)
    ap.add_argument("--pollers", type=int, default=0)
    ap.add_argument("--poll-hz", type=float, default=1.0)
    ap.add_argument("--time-scale", type=float, default=0.1,
                    help="--pollers: the simulated printer's time scale (0.1: moves 10x fast)")
    ap.add_argument("--slow-heads", type=int, default=0)
    ap.add_argument("--every-s", type=float, default=10.0)
    ap.add_argument("--poll-worker", nargs=4, metavar=("PORT", "CLIENTS", "HZ", "SECONDS"))
    args = ap.parse_args()
    if args.poll_worker:
        port, clients, hz, seconds = args.poll_worker
        return web_load.poll_worker(int(port), int(clients), float(hz), float(seconds))
    if args.pollers:
        return pollers_main(args)
    if args.slow_heads:
        return slow_heads_main(args)
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
