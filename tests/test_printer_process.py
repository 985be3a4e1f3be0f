"""PrinterProcess: the same driver in a child process, with the parent mirroring it."""

import json
import os
import subprocess
import sys
import threading
import time

import pytest

from hostd.printer import LinkSettings
from hostd.printer.process import PrinterProcess
from hostd.printer.sim import Simulator
from hostd.printer.simconfig import SimConfig

from printer_helpers import HOUSEKEEPING, job_commands, moves

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_process_link_streams_exactly_and_mirrors_state():
    sim = Simulator(SimConfig(advanced_ok=True, time_scale=0, boot_s=0.05, seed=2, fault_corrupt=0.01),
                    baud=250000)
    path = sim.start()
    lines = moves(1000)
    events = []
    try:
        with PrinterProcess(path, LinkSettings(baud=250000, banner_quiet_s=0.05),
                            on_event=lambda e: events.append(e.kind)) as printer:
            info = printer.connect()
            assert info["FIRMWARE_NAME"].startswith("Marlin") and printer.state == "idle"
            job = printer.start(lines, job_id="j1")
            result = printer.wait(30)
            assert result["result"] == "done" and result["confirmed"] == 1000 and job.id == "j1"
            assert printer.state == "idle"
            assert printer.stats["resends"] >= 1
            assert {"state", "job", "progress"} <= set(events)
        assert job_commands(sim) == lines
    finally:
        sim.stop()


@pytest.mark.slow     # burns three cores' worth of Python on purpose
def test_process_link_keeps_streaming_while_this_process_is_busy(tmp_path):
    """Busy Python threads here cannot take the GIL from the link in its own process.

    The simulator runs as ``hostd sim-printer`` in a third process, like a real printer.
    """
    link = str(tmp_path / "printer")
    record = str(tmp_path / "record.json")
    sim = subprocess.Popen([sys.executable, "-m", "hostd", "sim-printer", "--baud", "250000",
                            "--link", link, "--record", record, "--advanced-ok", "1",
                            "--time-scale", "0", "--boot-s", "0.05"],
                           cwd=ROOT, stdout=subprocess.PIPE, text=True)
    stop = threading.Event()

    def burn():
        while not stop.is_set():
            sum(i * i for i in range(10000))

    lines = moves(1500)
    try:
        assert sim.stdout.readline().startswith("/dev/")
        with PrinterProcess(link, LinkSettings(baud=250000, banner_quiet_s=0.05)) as printer:
            printer.connect()
            burners = [threading.Thread(target=burn, daemon=True) for _ in range(3)]
            for thread in burners:
                thread.start()
            result = printer.wait(60) if printer.start(lines) else None
            stop.set()
            assert result["result"] == "done"
            utilisation = result["bytes_sent"] / result["seconds"] / 25000.0
            print("measured link utilisation with 3 busy threads = %.3f" % utilisation)
            # A thread-based link manages about a sixth of the link here (see the benchmark).
            assert utilisation > 0.5
    finally:
        stop.set()
        sim.terminate()
        sim.wait(10)
    with open(record) as handle:
        executed = json.load(handle)["commands"]
    assert [c for c in executed if c.split()[0] not in HOUSEKEEPING] == lines


def test_process_link_reports_firmware_errors_and_cancel():
    sim = Simulator(SimConfig(advanced_ok=True, time_scale=0, boot_s=0.05, fault_runaway_line=100),
                    baud=250000)
    path = sim.start()
    try:
        with PrinterProcess(path, LinkSettings(baud=250000, banner_quiet_s=0.05)) as printer:
            printer.connect()
            printer.start(moves(300))
            result = printer.wait(30)
            assert result["result"] == "error"
            assert result["error"] == "Error:Thermal Runaway, system stopped! Heater_ID: 0"
            assert printer.state == "error"
            printer.connect()
            printer.start(moves(2000, feed_mm_min=600))
            time.sleep(0.3)
            printer.cancel()
            assert printer.wait(30)["result"] == "cancelled"
    finally:
        sim.stop()
