"""Port kinds: ``sim://`` in process, and ``socket://`` to a ser2net-style bridge."""

import errno
import os
import select
import socket
import threading

import pytest
import serial

from hostd.printer import LinkSettings, Printer, PrinterError, transport
from hostd.printer.sim import Simulator
from hostd.printer.simconfig import SimConfig

from printer_helpers import job_commands, moves


def test_sim_url_runs_the_simulator_in_process():
    lines = moves(200)
    with Printer("sim://?advanced_ok=1&time_scale=0&planner=8", LinkSettings(baud=250000)) as printer:
        printer.connect()
        assert printer.simulator.config.planner == 8
        assert printer.capabilities["ADVANCED_OK"]
        printer.start(lines)
        assert printer.wait(30)["result"] == "done"
        assert job_commands(printer.simulator) == lines


def _bridge(listener, device_path, stop):
    """Accept one TCP client and shuttle bytes to and from the serial device (ser2net)."""
    client, _ = listener.accept()
    device = serial.Serial(device_path, 250000, timeout=0)
    fd = device.fileno()
    try:
        while not stop.is_set():
            ready, _, _ = select.select([client, fd], [], [], 0.05)
            if client in ready:
                data = client.recv(4096)
                if not data:
                    break
                device.write(data)
            if fd in ready:
                data = os.read(fd, 4096)
                if data:
                    client.sendall(data)
    finally:
        device.close()
        client.close()


def test_socket_url_through_a_network_serial_bridge():
    sim = Simulator(SimConfig(advanced_ok=True, time_scale=0), baud=250000)
    path = sim.start()
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    stop = threading.Event()
    bridge = threading.Thread(target=_bridge, args=(listener, path, stop), daemon=True)
    bridge.start()
    lines = moves(300)
    try:
        url = "socket://127.0.0.1:%d" % listener.getsockname()[1]
        with Printer(url, LinkSettings(baud=250000)) as printer:
            printer.connect()
            printer.start(lines)
            assert printer.wait(30)["result"] == "done"
        assert job_commands(sim) == lines
    finally:
        stop.set()
        bridge.join(5)
        listener.close()
        sim.stop()


def test_start_line_continues_an_interrupted_job_and_close_ends_the_job():
    lines = moves(300)
    with Printer("sim://?advanced_ok=1&time_scale=0", LinkSettings(baud=250000)) as printer:
        printer.connect()
        job = printer.start(lines, start_line=101)
        assert job.total == 200
        assert printer.wait(30)["result"] == "done"
        assert job_commands(printer.simulator) == lines[100:]
        assert job.last_confirmed_line == 300
        slow = printer.start(["G1 X10 F60", "G1 X0 F60"])
    # close() ends it, never hangs, and runs the cancel script on the way out.
    assert slow.wait(5) and slow.result == "cancelled"


class _ClosedUnderRead:
    """A port whose read fails the way pyserial's socket:// handler does once closed."""

    in_waiting = 0

    def read(self, n):
        raise ValueError("file descriptor cannot be a negative integer (-1)")


def test_reader_reports_a_port_closed_under_its_read():
    import queue

    from hostd.printer.transport import Reader

    inbox = queue.Queue()
    reader = Reader(_ClosedUnderRead(), inbox, generation=7)
    reader.start()
    reader.join(5)
    assert not reader.is_alive()
    kind, generation, reason = inbox.get_nowait()
    assert (kind, generation) == ("lost", 7) and "port lost" in reason


def test_a_port_this_user_may_not_open_says_how_to_get_access(monkeypatch):
    def refuse(url, **kwargs):  # what pyserial raises for a port of group dialout
        raise serial.SerialException(errno.EACCES, "could not open port %s: [Errno 13] "
                                     "Permission denied: %r" % (url, url))

    monkeypatch.setattr(serial, "serial_for_url", refuse)
    with pytest.raises(PrinterError) as info:
        transport.open_port("/dev/ttyACM0", 115200)
    assert info.value.code == "port"
    assert "cannot open /dev/ttyACM0" in info.value.message
    assert "usermod -aG dialout" in info.value.message


def test_a_port_is_held_exclusively():
    sim = Simulator(SimConfig(boot_s=0.0), baud=250000)
    sim.start()
    try:
        path = sim.wait_port()
        first = transport.open_port(path, 250000)
        try:
            with pytest.raises(PrinterError) as info:
                transport.open_port(path, 250000)
            assert "another program holds the port" in info.value.message
        finally:
            transport.close_port(first)
        transport.close_port(transport.open_port(path, 250000))   # free again once closed
    finally:
        sim.stop()
