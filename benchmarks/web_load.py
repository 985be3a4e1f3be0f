"""Load on the page beside a print: many pollers, and clients trickling request heads.

Used by ``benchmarks/web.py --pollers N`` and ``--slow-heads N`` (see there); each runs
``hostd run`` as a real process on 127.0.0.1, every loop bounded in count and time.
"""

import http.client
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIM_OPTIONS = dict(advanced_ok=1, boot_s=0.0, hotend_tau_s=0.3, bed_tau_s=0.3)


def status(port, timeout=60):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        conn.request("GET", "/api/status")
        return json.loads(conn.getresponse().read())
    finally:
        conn.close()


def cpu_s(pid):
    """User + system CPU seconds of process ``pid`` and its children that were waited for."""
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return sum(int(v) for v in fields[11:15]) / os.sysconf("SC_CLK_TCK")


def child_pids(pid):
    try:
        with open("/proc/%d/task/%d/children" % (pid, pid)) as f:
            return [int(p) for p in f.read().split()]
    except OSError:
        return []


# -- pollers: a separate process, so their GIL is not the simulator's or ours ----------------

def poll_worker(port, clients, hz, seconds):
    """``clients`` threads each GET /api/status ``hz`` times a second for ``seconds``; prints
    {"requests", "errors"} as JSON when done. Runs as ``web.py --poll-worker ...``."""
    counts, errors = [0] * clients, [0] * clients
    start = time.monotonic()
    end = start + seconds

    def run(i):
        conn = None
        n = 0
        while True:
            due = start + (i / clients + n) / hz
            if due >= end:
                break
            time.sleep(max(0.0, due - time.monotonic()))
            n += 1
            try:
                conn = conn or http.client.HTTPConnection("127.0.0.1", port, timeout=30)
                conn.request("GET", "/api/status")
                r = conn.getresponse()
                r.read()
                counts[i] += r.status == 200
            except (OSError, http.client.HTTPException):
                errors[i] += 1
                conn = None
    threads = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(seconds + 60)
    print(json.dumps({"requests": sum(counts), "errors": sum(errors),
                      "seconds": time.monotonic() - start}), flush=True)


def stream_rate(port, seconds, pollers=0, hz=1.0):
    """Serial lines/s over ``seconds`` (the link's lines_sent), with ``pollers`` polling."""
    worker = None
    if pollers:
        worker = subprocess.Popen([sys.executable, str(ROOT / "benchmarks" / "web.py"),
                                   "--poll-worker", str(port), str(pollers), str(hz),
                                   str(seconds + 4)], stdout=subprocess.PIPE, text=True)
        time.sleep(2.0)                 # its threads connected and polling
    s0 = status(port)
    t0, c0 = time.monotonic(), time.process_time()
    time.sleep(seconds)
    s1 = status(port)
    t1 = time.monotonic()
    out = {"pollers": pollers, "window_s": round(t1 - t0, 2)}
    p0, p1 = s0["printers"][0], s1["printers"][0]
    out["lines_per_s"] = round((p1["lines_sent"] - p0["lines_sent"]) / (t1 - t0), 1)
    if p1.get("starvation_s") is not None and p0.get("starvation_s") is not None:
        # sim:// only: time the simulated planner ran dry waiting for lines from the host
        out["starvation_s"] = round(p1["starvation_s"] - p0["starvation_s"], 3)
    out["still_printing"] = s1["printers"][0]["state"] == "printing"
    out["bench_cpu_s"] = round(time.process_time() - c0, 2)
    if worker is not None:
        done = json.loads(worker.communicate(timeout=seconds + 120)[0])
        out["status_rps"] = round(done["requests"] / done["seconds"], 1)
        out["poll_errors"] = done["errors"]
    return out


# -- slow heads --------------------------------------------------------------------------------

class Trickle:
    """``count`` connections each sending one header line every ``every_s`` (staggered),
    reopening one the server closed, like a client that keeps trying."""

    def __init__(self, port, count, every_s):
        self.port, self.count, self.every_s = port, count, every_s
        self.socks, self.reopened, self.refused = [], 0, 0
        self.stop = threading.Event()
        for _ in range(count):
            self.socks.append(self._open())
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _open(self):
        try:
            s = socket.create_connection(("127.0.0.1", self.port), timeout=2)
            s.setblocking(False)
            s.send(b"GET / HTTP/1.1\r\nHost: localhost\r\n")
            return s
        except OSError:
            self.refused += 1
            return None

    def _run(self):
        n = 0
        while not self.stop.is_set():
            i = n % self.count
            n += 1
            self.stop.wait(self.every_s / self.count)
            s = self.socks[i]
            try:
                if s is None:
                    raise OSError
                s.send(b"X-Slow-%d: 1\r\n" % n)
            except BlockingIOError:
                pass
            except OSError:
                if s is not None:
                    s.close()
                self.socks[i] = self._open()
                self.reopened += 1

    def close(self):
        self.stop.set()
        self.thread.join(10)
        for s in self.socks:
            if s is not None:
                s.close()


def probe(port, method, path, token=None, timeout=5.0):
    """(status or None, seconds) of one request on a new connection."""
    t = time.perf_counter()
    try:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
        headers = {"Authorization": "Bearer " + token} if token else {}
        conn.request(method, path, headers=headers)
        code = conn.getresponse().status
        conn.close()
    except (OSError, http.client.HTTPException):
        code = None
    return code, time.perf_counter() - t


def slow_heads(port, token, count, every_s, seconds):
    """Probe the page, /healthz and the emergency stop once a second while ``count``
    connections trickle headers; how many were answered, and how fast."""
    crowd = Trickle(port, count, every_s)
    time.sleep(min(every_s, 5.0))
    answered, total, lat = {}, {}, []
    end = time.monotonic() + seconds
    targets = [("GET", "/healthz", None), ("GET", "/", None),
               ("POST", "/api/printers/nope/estop", token)]   # answered 404: reached the app
    n = 0
    while time.monotonic() < end and n < 10 * seconds:
        method, path, tok = targets[n % len(targets)]
        n += 1
        code, took = probe(port, method, path, tok)
        total[path] = total.get(path, 0) + 1
        if code is not None:
            answered[path] = answered.get(path, 0) + 1
            lat.append(took)
        time.sleep(max(0.0, 1.0 - took))
    crowd.close()
    lat.sort()
    return {"connections": count, "every_s": every_s, "window_s": seconds,
            "answered": {p: "%d/%d" % (answered.get(p, 0), total[p]) for p in total},
            "median_ms": round(1000 * lat[len(lat) // 2], 1) if lat else None,
            "max_ms": round(1000 * lat[-1], 1) if lat else None,
            "reopened": crowd.reopened, "refused": crowd.refused}
