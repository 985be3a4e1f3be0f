"""``hostd stream`` end to end through ``hostd sim-printer`` on a real pty (two processes)."""

import contextlib
import json
import os
import pty
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from printer_helpers import HOUSEKEEPING, moves

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def hostd(*args, **kwargs):
    return [sys.executable, "-m", "hostd"] + list(args)


@pytest.fixture
def sim_printer(tmp_path):
    """Start ``hostd sim-printer`` with the given flags; yields (link path, record file)."""
    procs = []

    def start(*flags):
        link = str(tmp_path / "printer")
        record = str(tmp_path / "record.json")
        proc = subprocess.Popen(hostd("sim-printer", "--link", link, "--record", record, *flags),
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(proc)
        path = proc.stdout.readline().strip()
        if not path.startswith("/dev/"):
            proc.kill()
            pytest.fail("sim-printer printed %r: %s" % (path, proc.stderr.read()))
        assert os.path.realpath(link) == path
        return link, record, proc

    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(10)


def stop(proc, record):
    proc.terminate()
    assert proc.wait(10) == 0
    with open(record) as handle:
        return json.load(handle)


def test_stream_through_sim_printer_prints_the_json_line(sim_printer, tmp_path):
    lines = ["G28", "M104 S200", "M109 S200", "G92 E0"] + moves(800)
    gcode = tmp_path / "part.gcode"
    gcode.write_text("; generated\n" + "\n".join(line + " ; comment" for line in lines) + "\n")
    link, record, proc = sim_printer("--baud", "250000", "--advanced-ok", "1", "--time-scale", "0",
                                     "--fault-corrupt", "0.01", "--seed", "7")
    done = subprocess.run(hostd("stream", str(gcode), "--port", link, "--baud", "250000"),
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    out = done.stdout.strip().splitlines()
    assert len(out) == 1
    summary = json.loads(out[0])
    assert set(summary) == {"lines", "bytes", "resends", "seconds", "lines_per_s", "link_utilisation",
                            "result", "error"}
    assert summary["result"] == "done" and summary["error"] is None
    assert summary["lines"] == len(lines)
    assert summary["resends"] >= 5
    assert 0 < summary["link_utilisation"] <= 1.05
    assert abs(summary["lines_per_s"] - summary["lines"] / summary["seconds"]) < 1
    recorded = stop(proc, record)
    executed = [c for c in recorded["commands"] if c.split()[0] not in HOUSEKEEPING]
    assert executed == lines
    assert recorded["stats"]["rx_overruns"] == 0


def test_stream_reports_firmware_error_and_exits_non_zero(sim_printer, tmp_path):
    gcode = tmp_path / "part.gcode"
    gcode.write_text("\n".join(moves(300)) + "\n")
    link, record, proc = sim_printer("--baud", "250000", "--time-scale", "0", "--fault-runaway-line", "100")
    done = subprocess.run(hostd("stream", str(gcode), "--port", link, "--baud", "250000"),
                          cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode != 0
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["result"] == "error"
    assert summary["error"] == "Error:Thermal Runaway, system stopped! Heater_ID: 0"
    assert 0 < summary["lines"] < 100


def test_stream_to_missing_port_fails_cleanly(tmp_path):
    gcode = tmp_path / "part.gcode"
    gcode.write_text("G1 X1\n")
    started = time.monotonic()
    done = subprocess.run(hostd("stream", str(gcode), "--port", str(tmp_path / "nothing"),
                                "--open-timeout", "0.5"),
                          cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode != 0
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["result"] == "error" and "cannot open" in summary["error"]
    assert "Traceback" not in done.stderr
    assert time.monotonic() - started < 30


def _terminal_sigint():
    # A runner that starts the suite in the background (``cmd &``) hands its children
    # SIGINT ignored, and Python then never raises KeyboardInterrupt: give the stream
    # what a terminal gives a foreground command.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@contextlib.contextmanager
def terminal_stream(*args):
    """``hostd stream ARGS`` with stderr on a pty, as at a terminal (progress shown).

    Yields (process, shown): ``shown()`` is the text written to the terminal so far.
    """
    master, slave = pty.openpty()
    proc = subprocess.Popen(hostd("stream", *args), cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=slave, text=True, preexec_fn=_terminal_sigint)
    os.close(slave)
    chunks = []

    def drain():    # keep the pty empty so the stream never blocks writing its bar
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:     # the stream has exited: its end of the pty is closed
                return
            if not chunk:
                return
            chunks.append(chunk)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        yield proc, lambda: b"".join(chunks).decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(5)
        os.close(master)


def wait_shown(proc, shown, pattern, timeout_s=60):
    deadline = time.monotonic() + timeout_s
    while not re.search(pattern, shown()):
        assert proc.poll() is None and time.monotonic() < deadline, shown()
        time.sleep(0.05)


def test_ctrl_c_cancels_the_stream(sim_printer, tmp_path):
    gcode = tmp_path / "part.gcode"
    gcode.write_text("\n".join(moves(2000, feed_mm_min=600)) + "\n")    # minutes of printing
    link, record, proc = sim_printer("--baud", "250000", "--advanced-ok", "1", "--time-scale", "0.5")
    with terminal_stream(str(gcode), "--port", link, "--baud", "250000") as (stream, shown):
        wait_shown(stream, shown, r" [1-9][0-9]*/2000 lines")     # printing
        stream.send_signal(signal.SIGINT)
        out, _ = stream.communicate(timeout=30)
    assert stream.returncode == 1, shown()
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["result"] == "cancelled", shown()
    assert 0 < summary["lines"] < 2000
    assert "cancelling" in shown()
    recorded = stop(proc, record)
    assert recorded["commands"][-1] == "M84"      # the cancel script ran to its end


def test_ctrl_c_while_connecting_ends_with_the_json_line(sim_printer, tmp_path):
    gcode = tmp_path / "part.gcode"
    gcode.write_text("\n".join(moves(100)) + "\n")
    # The firmware takes 20 s to boot: the stream waits in its handshake.
    link, record, proc = sim_printer("--baud", "250000", "--boot-s", "20")
    with terminal_stream(str(gcode), "--port", link, "--baud", "250000") as (stream, shown):
        wait_shown(stream, shown, r"connecting to .* at 250000 baud")
        started = time.monotonic()
        stream.send_signal(signal.SIGINT)
        out, _ = stream.communicate(timeout=30)
        elapsed = time.monotonic() - started
    assert stream.returncode == 1, shown()
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["result"] == "cancelled" and summary["lines"] == 0, summary
    assert "before printing" in summary["error"] and "Traceback" not in shown()
    assert elapsed < 10, elapsed    # not after the firmware has booted


def test_an_unforeseen_error_still_ends_with_the_json_line(monkeypatch, capsys, tmp_path):
    """Scripts read the last line: it is written even when the link fails in a way
    nobody caught (the error then follows as a traceback)."""
    import argparse
    from hostd.commands import stream

    class Broken:
        def __init__(self, *a, **k):
            pass

        def connect(self):
            raise RuntimeError("a fault of the link's own")

        def close(self):
            pass
    monkeypatch.setattr(stream, "Printer", Broken)
    args = argparse.Namespace(file=str(tmp_path / "x.gcode"), port="sim://", baud=115200,
                              ping_pong=False, ok_timeout=5.0, open_timeout=5.0,
                              no_progress=True)
    with pytest.raises(RuntimeError):
        stream.run(args)
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["result"] == "error"
