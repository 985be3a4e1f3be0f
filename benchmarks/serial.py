"""Serial link benchmark: lines/s and link utilisation of the printer driver.

For each baud rate (115200 and 250000 by default) it streams a long file of short moves
through ``hostd sim-printer`` (a separate process on a real pty, as a printer would be):

- ``send_ahead``: ADVANCED_OK firmware, printer infinitely fast (time_scale 0), so the
  link is the only limit; target: link utilisation >= 0.90.
- ``ping_pong``: one line in flight; compared with the simulator's round-trip limit,
  i.e. what a minimal host loop (write a line, read its ok, nothing else) achieves on
  the same simulator; target: within 10 %.
- ``round_trip_limit``: that minimal loop, plus the wire-only bound
  (line + ok bytes at baud/10).
- ``cpu_load_115200``: the 80 mm/s run again with busy Python threads in the host
  process (a planner's stand-in), link in a thread (``Printer``) versus in its own
  process (``PrinterProcess``).
- ``starvation_115200``: at 115200 baud, the printer moving in real time (time_scale 1)
  at print speeds of 40, 80 and 120 mm/s: seconds the planner sat empty between moves
  (target: 0). The first move starts from rest and is not counted.

Prints one JSON document on stdout. Usage::

    .venv/bin/python benchmarks/serial.py [--gcode FILE] [--lines 20000] [--bauds 115200,250000]
"""

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
# This file is named serial.py: keep its folder off the path or it shadows pyserial.
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != HERE]
sys.path.insert(0, ROOT)

import serial  # noqa: E402

from hostd.printer import LinkSettings, Printer, PrinterProcess  # noqa: E402
from hostd.printer import protocol  # noqa: E402

TARGET_SEND_AHEAD_UTILISATION = 0.90
TARGET_PING_PONG_OF_LIMIT = 0.90


def generate_moves(count, segment_mm=0.4):
    """Short G1 moves along a meandering path with varying layer height and extrusion,
    like a thickness-varying 4D-printing path (Z and E change on every move)."""
    lines = ["G21", "G90", "M82", "G92 E0"]
    x, y, e = 20.0, 20.0, 0.0
    for i in range(count):
        heading = 0.3 * math.sin(i / 25.0) + (math.pi if (i // 300) % 2 else 0.0)
        x += segment_mm * math.cos(heading)
        y += segment_mm * math.sin(heading) + (0.4 if i % 300 == 299 else 0.0)
        thickness = 0.16 + 0.08 * (0.5 + 0.5 * math.sin(i / 60.0))
        z = 0.2 + thickness
        e += segment_mm * thickness * 0.42 / 2.405   # 0.42 mm line width, 1.75 mm filament
        lines.append("G1 X%.3f Y%.3f Z%.3f E%.5f" % (x, y, z, e))
    return lines


def _mean_move_mm(lines):
    """Mean XYZ length of the G0/G1 moves (absolute coordinates assumed)."""
    last = {"X": 0.0, "Y": 0.0, "Z": 0.0}
    total, count = 0.0, 0
    for line in lines:
        words = line.split()
        if not words or words[0] not in ("G0", "G1"):
            continue
        new = dict(last)
        for word in words[1:]:
            if word[0] in new:
                try:
                    new[word[0]] = float(word[1:])
                except ValueError:
                    pass
        length = math.dist([last[a] for a in "XYZ"], [new[a] for a in "XYZ"])
        if length > 0:
            total += length
            count += 1
        last = new
    return total / count if count else float("nan")


def read_gcode(path):
    with open(path, encoding="ascii", errors="replace") as handle:
        return [c for c in (protocol.clean(raw) for raw in handle) if c]


class SimProcess:
    """``hostd sim-printer`` in its own process, published under a symlink."""

    def __init__(self, folder, baud, *flags):
        self.link = os.path.join(folder, "printer-%d" % baud)
        self.record = self.link + ".json"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hostd", "sim-printer", "--baud", str(baud), "--link", self.link,
             "--record", self.record] + [str(f) for f in flags],
            cwd=ROOT, stdout=subprocess.PIPE, text=True)
        self.path = self.proc.stdout.readline().strip()
        if not self.path:
            raise RuntimeError("sim-printer did not start")

    def stop(self):
        self.proc.terminate()
        self.proc.wait(30)
        with open(self.record) as handle:
            return json.load(handle)["stats"]


def stream(folder, baud, lines, send_ahead, sim_flags, feed_mm_min=None, real_time=False, process=False):
    sim = SimProcess(folder, baud, *sim_flags)
    body = list(lines)
    if feed_mm_min:
        body.insert(0, "G1 F%d" % feed_mm_min)
    link_class = PrinterProcess if process else Printer
    printer = link_class(sim.link, LinkSettings(baud=baud, send_ahead=send_ahead, reconnect=False))
    try:
        printer.connect()
        printer.start(body)
        job = printer.wait(3600)
        stats = dict(printer.stats)
    finally:
        printer.close()
        sim_stats = sim.stop()
    seconds = job["seconds"]
    run = dict(
        result=job["result"], lines=job["confirmed"], bytes=job["bytes_sent"], seconds=round(seconds, 3),
        lines_per_s=round(job["confirmed"] / seconds, 1),
        link_utilisation=round(job["bytes_sent"] / seconds / (baud / 10.0), 4),
        mean_line_bytes=round(job["bytes_sent"] / max(1, stats["lines_sent"]), 1),
        max_in_flight_lines=stats["max_in_flight_lines"], max_in_flight_bytes=stats["max_in_flight_bytes"],
        resends=stats["resends"], rx_overruns=sim_stats["rx_overruns"])
    if real_time:   # with time_scale 0 every gap between moves is "starvation": meaningless
        run.update(starvation_s=round(sim_stats["starvation_s"], 4),
                   starvation_events=sim_stats["starvation_events"],
                   max_starvation_gap_s=round(sim_stats["max_starvation_gap_s"], 4))
    return run


def round_trip_limit(folder, baud, lines, count):
    """A minimal ping-pong host: frame, write, read until ok. No driver, no threads."""
    sim = SimProcess(folder, baud, "--time-scale", "0", "--autoreport", "0")
    port = serial.Serial(sim.path, baud, timeout=2)
    try:
        deadline = time.monotonic() + 5
        while b"start" not in port.readline() and time.monotonic() < deadline:
            pass
        time.sleep(0.3)
        port.reset_input_buffer()
        port.write(protocol.frame(0, "M110 N0"))
        port.readline()
        sent = 0
        started = time.monotonic()
        for n, command in enumerate(lines[:count], 1):
            data = protocol.frame(n, command)
            port.write(data)
            sent += len(data)
            while not port.readline().startswith(b"ok"):
                pass
        seconds = time.monotonic() - started
    finally:
        port.close()
        sim.stop()
    done = min(count, len(lines))
    mean_line = sent / done
    wire_s = (mean_line + 3) * 10.0 / baud        # the line out, "ok\n" back
    return dict(lines=done, lines_per_s=round(done / seconds, 1),
                link_utilisation=round(sent / seconds / (baud / 10.0), 4),
                wire_only_lines_per_s=round(1.0 / wire_s, 1), mean_line_bytes=round(mean_line, 1))


def cpu_load(folder, lines, threads, speed_mm_s=80.0):
    """Starvation at 115200 baud, 80 mm/s, with busy Python threads in the host process:
    the link in a thread of that process versus the link in its own process."""
    stop = threading.Event()

    def burn():
        while not stop.is_set():
            sum(i * i for i in range(10000))

    result = dict(busy_threads=threads, print_speed_mm_s=speed_mm_s, moves=len(lines))
    for mode, process in (("thread", False), ("process", True)):
        stop.clear()
        burners = [threading.Thread(target=burn, daemon=True) for _ in range(threads)]
        for thread in burners:
            thread.start()
        try:
            run = stream(folder, 115200, lines, True, ["--advanced-ok", "1", "--time-scale", "1"],
                         feed_mm_min=int(speed_mm_s * 60), real_time=True, process=process)
        finally:
            stop.set()
            for thread in burners:
                thread.join()
        run["meets_target"] = run["starvation_s"] == 0.0
        result[mode] = run
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gcode", help="stream this file instead of generated moves")
    parser.add_argument("--lines", type=int, default=20000, help="generated moves (default 20000)")
    parser.add_argument("--bauds", default="115200,250000")
    parser.add_argument("--limit-lines", type=int, default=3000, help="lines for the round-trip limit")
    parser.add_argument("--starvation-lines", type=int, default=3000,
                        help="moves streamed in real time for the starvation figure")
    parser.add_argument("--cpu-load", type=int, default=3,
                        help="busy Python threads in this process for the load runs (default 3)")
    parser.add_argument("--sections", default="link,starvation,cpu_load",
                        help="which parts to run (default link,starvation,cpu_load)")
    parser.add_argument("--print-speeds", default="40,80,120",
                        help="mm/s for the real-time starvation runs (default 40,80,120)")
    args = parser.parse_args(argv)

    lines = read_gcode(args.gcode) if args.gcode else generate_moves(args.lines)
    report = dict(source=args.gcode or "generated: %d short moves (0.4 mm, varying Z and E)" % args.lines,
                  commands=len(lines), python=sys.version.split()[0], cpus=os.cpu_count(),
                  targets=dict(send_ahead_link_utilisation=TARGET_SEND_AHEAD_UTILISATION,
                               ping_pong_of_round_trip_limit=TARGET_PING_PONG_OF_LIMIT,
                               starvation_s=0.0),
                  runs={})
    sections = args.sections.split(",")
    with tempfile.TemporaryDirectory(prefix="hostd-bench-") as folder:
        for baud in [int(b) for b in args.bauds.split(",")] if "link" in sections else []:
            fast = ["--time-scale", "0", "--autoreport", "1"]
            run = dict(
                send_ahead=stream(folder, baud, lines, True, ["--advanced-ok", "1"] + fast),
                ping_pong=stream(folder, baud, lines, False, ["--advanced-ok", "0"] + fast),
                round_trip_limit=round_trip_limit(folder, baud, lines, args.limit_lines))
            run["send_ahead"]["meets_target"] = run["send_ahead"]["link_utilisation"] >= TARGET_SEND_AHEAD_UTILISATION
            ratio = run["ping_pong"]["lines_per_s"] / run["round_trip_limit"]["lines_per_s"]
            run["ping_pong"]["of_round_trip_limit"] = round(ratio, 3)
            run["ping_pong"]["meets_target"] = ratio >= TARGET_PING_PONG_OF_LIMIT
            report["runs"][str(baud)] = run
            print("baud %d done" % baud, file=sys.stderr)
        realistic = lines[:args.starvation_lines]
        if "cpu_load" in sections:
            report["cpu_load_115200"] = cpu_load(folder, realistic, args.cpu_load)
            print("cpu load runs done", file=sys.stderr)
        report["starvation_115200"] = []
        for speed in [float(v) for v in args.print_speeds.split(",")] if "starvation" in sections else []:
            row = dict(print_speed_mm_s=speed, moves=len(realistic),
                       moves_per_s_needed=round(speed / _mean_move_mm(realistic), 1))
            for mode, send_ahead, advanced in (("send_ahead", True, "1"), ("ping_pong", False, "0")):
                row[mode] = stream(folder, 115200, realistic, send_ahead,
                                   ["--advanced-ok", advanced, "--time-scale", "1"],
                                   feed_mm_min=int(speed * 60), real_time=True)
                row[mode]["meets_target"] = row[mode]["starvation_s"] == 0.0
            report["starvation_115200"].append(row)
            print("starvation at %g mm/s done" % speed, file=sys.stderr)
    json.dump(report, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
