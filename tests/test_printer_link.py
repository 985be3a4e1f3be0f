"""The driver against the simulated printer on real pseudo-terminals.

Time scales keep the set short; bounds are generous and measured values are reported
through ``record_property`` (visible with ``pytest -rA`` / junit) rather than asserted
tightly, so a loaded CI box does not make these flaky.
"""

import os
import select
import threading
import time

import pytest

from hostd.printer import LinkSettings, PrinterError
from hostd.printer import protocol
from hostd.printer.settings import DEFAULT_CANCEL_GCODE, DEFAULT_PAUSE_GCODE, DEFAULT_RESUME_GCODE

from printer_helpers import job_commands, moves, script, sim_and_printer


def report(record_property, name, value):
    """A measured value: in the junit XML and, with ``-rA``, in the captured output."""
    record_property(name, value)
    print("measured %s = %s" % (name, value))


def wait_for(predicate, timeout_s=10.0, what="condition"):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting for " + what)
        time.sleep(0.005)


# -- exactly once ------------------------------------------------------------------------

def test_exactly_once_with_corruption_and_lost_oks_send_ahead(record_property):
    lines = moves(3000)
    # Two lost oks in a row at the very end need the timeout recovery (M155 reports flow
    # all the while and must not count as answers).
    settings = LinkSettings(ok_timeout_s=0.5)
    with sim_and_printer(baud=1000000, settings=settings, advanced_ok=True, time_scale=0, seed=3, fault_corrupt=0.01,
                         fault_lost_ok=0.01, fault_noise=0.005) as (sim, printer):
        printer.start(lines)
        result = printer.wait(60)
        assert result["result"] == "done", result
        stats = sim.stats
        # The faults really happened, otherwise this test proves nothing.
        assert stats["corrupted"] >= 15 and stats["lost_oks"] >= 10
        assert job_commands(sim) == lines
        assert result["confirmed"] == 3000 and result["last_confirmed_line"] == 3000
        report(record_property, "resends", printer.stats["resends"])
        report(record_property, "seconds", result["seconds"])


def test_exactly_once_ping_pong_recovers_lost_oks_by_timeout(record_property):
    lines = moves(1000)
    settings = LinkSettings(ok_timeout_s=0.3)
    with sim_and_printer(baud=1000000, settings=settings, advanced_ok=False, time_scale=0, seed=5,
                         fault_corrupt=0.01, fault_lost_ok=0.004) as (sim, printer):
        printer.start(lines)
        result = printer.wait(60)
        assert result["result"] == "done", result
        assert sim.stats["lost_oks"] >= 1 and sim.stats["corrupted"] >= 3
        assert printer.stats["timeouts"] >= sim.stats["lost_oks"]
        assert job_commands(sim) == lines
        report(record_property, "timeouts", printer.stats["timeouts"])


# -- flow control ------------------------------------------------------------------------

def test_send_ahead_never_exceeds_firmware_buffers(record_property):
    # Short lines so the line count (not the byte count) is what binds, and slow moves
    # so the firmware's queue really fills up and stays full.
    lines = ["G1 F600"] + ["G1 X%d" % (i % 2) for i in range(300)]    # 5 ms per move
    settings = LinkSettings(rx_buffer_bytes=95)
    with sim_and_printer(settings=settings, advanced_ok=True, bufsize=6, rx_bytes=96, planner=8,
                         time_scale=0.05) as (sim, printer):
        printer.start(lines)
        assert printer.wait(60)["result"] == "done"
        stats = sim.stats
        assert stats["rx_overruns"] == 0
        assert stats["max_queue"] == 6                     # the queue was full ...
        assert printer.stats["max_in_flight_lines"] <= 6   # ... and never overrun
        assert printer.stats["max_in_flight_lines"] > 1    # send-ahead was used
        assert printer.stats["max_in_flight_bytes"] <= 95
        assert job_commands(sim) == lines
        report(record_property, "max_in_flight_lines", printer.stats["max_in_flight_lines"])


def test_send_ahead_respects_receive_buffer_bytes():
    lines = moves(250)    # ~45-byte lines: three do not fit in 96 bytes
    settings = LinkSettings(rx_buffer_bytes=95)
    with sim_and_printer(settings=settings, advanced_ok=True, bufsize=16, rx_bytes=96,
                         time_scale=0.05) as (sim, printer):
        printer.start(lines)
        assert printer.wait(60)["result"] == "done"
        assert sim.stats["rx_overruns"] == 0
        assert 1 < printer.stats["max_in_flight_lines"] <= 2
        assert printer.stats["max_in_flight_bytes"] <= 95


def test_ping_pong_without_advanced_ok_has_one_line_in_flight():
    lines = moves(300)
    with sim_and_printer(advanced_ok=False, time_scale=0.05) as (sim, printer):
        assert not printer.capabilities["ADVANCED_OK"]
        printer.start(lines)
        assert printer.wait(60)["result"] == "done"
        assert printer.stats["max_in_flight_lines"] == 1
        assert sim.stats["max_unacked"] == 1
        assert job_commands(sim) == lines


# -- pause, resume, cancel, emergency stop ------------------------------------------------

def test_pause_and_resume_continue_at_the_right_line():
    lines = moves(300, feed_mm_min=600)    # ~6 ms per move at time_scale 0.15
    with sim_and_printer(advanced_ok=True, time_scale=0.15) as (sim, printer):
        printer.start(lines)
        wait_for(lambda: printer.progress()["confirmed"] >= 50, what="50 lines")
        printer.pause()
        wait_for(lambda: printer.state == "paused", what="paused")
        paused_at = printer.progress()
        time.sleep(0.2)
        # Nothing more from the job while paused.
        assert printer.progress()["confirmed"] == paused_at["confirmed"]
        before = job_commands(sim)
        k = paused_at["sent"]
        pause = script(DEFAULT_PAUSE_GCODE)
        assert before == lines[:k] + pause
        printer.resume()
        result = printer.wait(60)
        assert result["result"] == "done"
        assert job_commands(sim) == lines[:k] + pause + script(DEFAULT_RESUME_GCODE) + lines[k:]


def test_cancel_runs_the_cancel_gcode():
    lines = moves(400, feed_mm_min=600)
    with sim_and_printer(advanced_ok=True, time_scale=0.25) as (sim, printer):
        printer.start(lines)
        wait_for(lambda: printer.progress()["confirmed"] >= 30, what="30 lines")
        printer.cancel()
        result = printer.wait(30)
        assert result["result"] == "cancelled"
        assert printer.state == "idle"
        executed = job_commands(sim)
        cancel = script(DEFAULT_CANCEL_GCODE)
        sent = result["sent"]
        assert sent < len(lines)
        assert executed == lines[:sent] + cancel


def test_closing_the_link_during_a_print_runs_the_cancel_script_first():
    # Whatever closes the link mid-print (a program exiting, Ctrl-C at the wrong moment),
    # the heaters must not stay on: the cancel script goes out before the port closes.
    lines = moves(400, feed_mm_min=600)
    with sim_and_printer(advanced_ok=True, time_scale=0.25) as (sim, printer):
        job = printer.start(lines)
        wait_for(lambda: printer.progress()["confirmed"] >= 30, what="30 lines")
        printer.close()
        result = job.snapshot()
        assert result["result"] == "cancelled"
        assert result["error"] == "cancelled because the link was closed"
        assert job_commands(sim) == lines[:result["sent"]] + script(DEFAULT_CANCEL_GCODE)


def test_cancel_on_the_printer_cancels_the_job():
    # Marlin's "Stop print" on a host print only sends //action:cancel.
    lines = moves(400, feed_mm_min=600)
    with sim_and_printer(advanced_ok=True, time_scale=0.25) as (sim, printer):
        events = printer.subscribe()
        printer.start(lines)
        wait_for(lambda: printer.progress()["confirmed"] >= 30, what="30 lines")
        sim.press("cancel")
        result = printer.wait(30)
        assert result["result"] == "cancelled" and result["error"] == "cancelled on the printer"
        sent = result["sent"]
        assert sent < len(lines)
        assert job_commands(sim) == lines[:sent] + script(DEFAULT_CANCEL_GCODE)
        seen = []
        while not events.empty():
            seen.append(events.get())
        assert any(e.kind == "action" and e.data["action"] == "cancel" for e in seen)


@pytest.mark.parametrize("pause,resume,park,unpark", [
    # Pause and resume on the printer's screen: the host parks and unparks with its scripts.
    ("pause", "resume", DEFAULT_PAUSE_GCODE, DEFAULT_RESUME_GCODE),
    # //action:paused: the firmware parked on its own (a filament change); the host stops
    # feeding, sends nothing of its own, and goes on at //action:resumed.
    ("paused", "resumed", "", "")])
def test_pause_from_the_printer_stops_the_feed_and_resume_continues(pause, resume, park, unpark):
    lines = moves(300, feed_mm_min=600)
    with sim_and_printer(advanced_ok=True, time_scale=0.15) as (sim, printer):
        printer.start(lines)
        wait_for(lambda: printer.progress()["confirmed"] >= 50, what="50 lines")
        sim.press(pause)
        wait_for(lambda: printer.state == "paused", what="paused from the printer")
        k = printer.progress()["sent"]
        time.sleep(0.2)
        assert printer.progress()["sent"] == k
        assert job_commands(sim) == lines[:k] + script(park)
        sim.press(resume)
        assert printer.wait(60)["result"] == "done"
        assert job_commands(sim) == lines[:k] + script(park) + script(unpark) + lines[k:]


def test_emergency_stop_reaches_firmware_quickly_with_full_queue(record_property):
    lines = ["G1 X%d F600" % (10 * (i % 2)) for i in range(200)]   # 1 s per move
    with sim_and_printer(baud=115200, advanced_ok=True, time_scale=1.0) as (sim, printer):
        printer.start(lines)
        # Planner (16) and command queue (4) full, lines waiting in the receive buffer.
        wait_for(lambda: sim.stats["max_queue"] >= 4 and len(sim.firmware.planner) >= 16,
                 what="full queue")
        sent_at = printer.estop()
        wait_for(lambda: sim.stats["emergency_stop_at"] is not None, timeout_s=5, what="M112")
        latency_s = sim.stats["emergency_stop_at"] - sent_at
        report(record_property, "estop_latency_ms", round(latency_s * 1000, 2))
        assert latency_s < 0.5
        assert sim.firmware.halted
        wait_for(lambda: printer.state == "error", what="error state")
        result = printer.wait(5)
        assert result["result"] == "error" and result["error"] == "emergency stop"
        executed_before = len(sim.commands())
        time.sleep(0.1)
        assert len(sim.commands()) == executed_before


# -- failures ----------------------------------------------------------------------------

def test_disconnect_mid_stream_interrupts_and_reconnect_works():
    lines = moves(1000)
    settings = LinkSettings(reconnect=False)
    with sim_and_printer(settings=settings, advanced_ok=True, time_scale=0,
                         fault_disconnect_line=500, reconnect_s=0.3) as (sim, printer):
        printer.start(lines)
        result = printer.wait(30)
        assert result["result"] == "interrupted" and result["interrupted"]
        assert printer.state == "disconnected"
        # Line numbers start at 3 after the handshake: file line k is N k+2.
        last = result["last_confirmed_line"]
        assert 400 < last < 500
        assert job_commands(sim)[:last] == lines[:last]
        printer.connect()
        assert printer.state == "idle"
        printer.start(lines[:50])
        assert printer.wait(30)["result"] == "done"
        assert sim.stats["connections"] == 2


def test_link_reconnects_by_itself_when_the_port_returns():
    settings = LinkSettings(reconnect=True, reconnect_interval_s=0.1)
    with sim_and_printer(settings=settings, advanced_ok=True, time_scale=0,
                         fault_disconnect_line=100, reconnect_s=0.3) as (sim, printer):
        states = printer.subscribe()
        printer.start(moves(300))
        assert printer.wait(30)["result"] == "interrupted"
        wait_for(lambda: printer.state == "idle", what="automatic reconnect")
        seen = []
        while not states.empty():
            seen.append(states.get().kind)
        assert "connected" in seen


def test_close_while_the_board_boots_ends_the_connect_at_once():
    # A board that takes 20 s to boot: close() must not wait for it (it joins the
    # driver thread for at most 5 s, then leaves it behind).
    from hostd.printer import Printer
    printer = Printer("sim://?boot_s=20&time_scale=0", LinkSettings(baud=250000))
    outcome = []

    def connect():
        try:
            printer.connect()
        except PrinterError as exc:
            outcome.append(exc)

    caller = threading.Thread(target=connect)
    caller.start()
    wait_for(lambda: printer.state == "connecting", what="connecting")
    time.sleep(0.3)                       # in the handshake, waiting for the banner
    printer.close()
    caller.join(10)
    assert not printer._thread.is_alive(), "close() left the driver in its handshake"
    assert outcome and "closed while connecting" in str(outcome[0])


def test_thermal_runaway_stops_the_job_and_is_reported_verbatim():
    lines = ["M104 S200"] + moves(600)
    with sim_and_printer(advanced_ok=True, time_scale=0, fault_runaway_line=200) as (sim, printer):
        errors = []
        printer.on_event = lambda e: errors.append(e.data["message"]) if e.kind == "firmware_error" else None
        printer.start(lines)
        result = printer.wait(30)
        assert result["result"] == "error"
        assert result["error"] == "Error:Thermal Runaway, system stopped! Heater_ID: 0"
        wait_for(lambda: len(errors) >= 2, timeout_s=5, what="kill message")
        assert errors[:2] == ["Error:Thermal Runaway, system stopped! Heater_ID: 0",
                              "Error:Printer halted. kill() called!"]
        assert printer.state == "error"
        assert len(job_commands(sim)) < 200
        with pytest.raises(PrinterError) as err:
            printer.start(lines)
        assert err.value.code == "state"
        printer.connect()                    # reopening resets the board
        assert printer.state == "idle"


def test_spurious_reset_interrupts_the_job():
    settings = LinkSettings(reconnect=False)
    with sim_and_printer(settings=settings, advanced_ok=True, time_scale=0,
                         fault_reset_line=150) as (sim, printer):
        printer.start(moves(500))
        result = printer.wait(30)
        assert result["result"] == "interrupted"
        assert "reset" in result["error"]
        assert 100 < result["last_confirmed_line"] < 150


def test_silent_printer_stops_the_job_with_a_clear_reason():
    """A firmware that answers the handshake and then never again."""
    master, slave = os.openpty()
    import tty
    tty.setraw(slave)
    path = os.ttyname(slave)
    stop = threading.Event()

    def firmware():
        buffer = b""
        while not stop.is_set():
            if not select.select([master], [], [], 0.05)[0]:
                continue
            buffer += os.read(master, 4096)
            while b"\n" in buffer:
                raw, buffer = buffer.split(b"\n", 1)
                number, command, _ = protocol.unframe(raw)
                if number is not None and number <= 2:
                    os.write(master, b"ok\n")      # M110, M115: then silence

    thread = threading.Thread(target=firmware, daemon=True)
    thread.start()
    from hostd.printer import Printer
    printer = Printer(path, LinkSettings(reset_wait_s=0.1, ok_timeout_s=0.2, max_timeouts=2,
                                         reconnect=False))
    try:
        printer.connect()
        printer.start(moves(10))
        result = printer.wait(10)
        assert result["result"] == "error"
        assert "not responding" in result["error"]
        assert printer.stats["timeouts"] == 3
    finally:
        printer.close()
        stop.set()
        thread.join()
        os.close(master)
        os.close(slave)


# -- temperatures ------------------------------------------------------------------------

def test_heating_blocks_with_busy_and_reports_temperatures():
    lines = ["M104 S200", "M140 S60", "M190 S60", "M109 S200"] + moves(50)
    # Heating takes longer than the answer timeout: busy messages must count as life.
    settings = LinkSettings(autoreport_s=1, ok_timeout_s=1.0)    # hotend: ~2 s to reach 200
    with sim_and_printer(settings=settings, advanced_ok=True, time_scale=0.05, hotend_tau_s=8, bed_tau_s=4,
                         keepalive_s=0.2) as (sim, printer):
        states = []
        printer.on_event = lambda e: states.append(e.data["state"]) if e.kind == "state" else None
        printer.start(lines)
        assert printer.wait(30)["result"] == "done"
        assert "heating" in states
        assert printer.stats["timeouts"] == 0
        # M155 S1 autoreports keep coming after the job.
        wait_for(lambda: len(printer.temperatures.history().get("T", ())) >= 2, what="2 reports")
        temps = printer.temperatures.current()
        assert temps["T"]["target"] == 200 and abs(temps["T"]["current"] - 200) < 2
        assert temps["B"]["target"] == 60
        assert job_commands(sim) == lines


def test_temperature_polling_without_autoreport_does_not_disturb_the_job():
    lines = moves(150, feed_mm_min=1200)
    settings = LinkSettings(temp_poll_s=0.05)
    with sim_and_printer(settings=settings, advanced_ok=False, autoreport=False,
                         time_scale=0.3) as (sim, printer):
        printer.start(lines)
        assert printer.wait(60)["result"] == "done"
        polls = [c for c in sim.commands() if c == "M105"]
        assert len(polls) >= 3
        assert "T" in printer.temperatures.current()
        assert job_commands(sim) == lines


def test_cancel_while_heating_breaks_the_wait():
    lines = ["M104 S200", "M109 S200"] + moves(100)
    # Heating would take ~100 s: the cancel must not wait for it.
    with sim_and_printer(advanced_ok=True, time_scale=1.0, hotend_tau_s=20) as (sim, printer):
        printer.start(lines)
        wait_for(lambda: printer.state == "heating", what="heating")
        started = time.monotonic()
        printer.cancel()
        result = printer.wait(20)
        assert result["result"] == "cancelled"
        assert time.monotonic() - started < 10
        # Lines already in the firmware's queue still run (as on a real printer).
        assert job_commands(sim) == lines[:result["sent"]] + script(DEFAULT_CANCEL_GCODE)
        wait_for(lambda: printer.temperatures.current().get("T", {}).get("target") == 0,
                 what="heater off reported")


def test_a_link_closed_while_it_connects_stops_cleanly(monkeypatch):
    """A daemon shut down while its printer connects: close() runs on another thread
    while connect() is starting the driver thread. Neither may fail on a thread that
    is not started yet; connect() says the link was closed."""
    import types
    from hostd.printer import link as link_module
    from hostd.printer.link import Printer
    holder = {}

    class Racing(threading.Thread):
        def start(self):
            closer = threading.Thread(target=holder["printer"].close)
            closer.start()
            closer.join(5)
            super().start()

    monkeypatch.setattr(link_module, "threading", types.SimpleNamespace(Thread=Racing))
    printer = Printer("/dev/null-hostd-no-such-port", LinkSettings())
    holder["printer"] = printer
    with pytest.raises(PrinterError) as err:
        printer.connect(timeout_s=2.0)
    assert err.value.code == "state" and "closed while connecting" in str(err.value)
