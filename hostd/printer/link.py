"""The printer driver: one thread that owns the serial link and streams jobs.

Every public method may be called from any thread; they post a request to the driver
thread and wait for it to be accepted, so all protocol state lives in one thread and a
busy caller (path planning, the web server) can never stall the stream. Only
:meth:`Printer.estop` writes to the port directly, bypassing queue and flow control.

States (``Printer.state``): ``disconnected``, ``connecting``, ``idle``, ``printing``,
``heating`` (printing, waiting on M109/M190), ``paused``, ``error`` (firmware error or
emergency stop: connect again to reset the board).

Events (callback ``on_event(event)`` in the driver thread -- keep it short -- and
queues from :meth:`Printer.subscribe`): :class:`Event` with ``kind`` in ``state``,
``job`` (started/finished with the job snapshot), ``progress``, ``temperature``,
``resend``, ``timeout``, ``firmware_error`` (verbatim ``Error:`` line), ``log``
(``echo:`` and other firmware chatter), ``estop``, ``connected``.
"""

import threading
import time

import serial

from hostd.printer.driver import CONNECTING, DISCONNECTED, ERROR_STATE, HEATING, IDLE, Driver
from hostd.printer.events import Event
from hostd.printer.errors import PrinterError
from hostd.printer.job import Job
from hostd.printer.job import PAUSED, PRINTING
from hostd.printer.settings import LinkSettings

# The states (strings) and Event are part of this module's interface.
__all__ = ["Printer", "Event", "DISCONNECTED", "CONNECTING", "IDLE", "PRINTING", "HEATING", "PAUSED",
           "ERROR_STATE"]


class Printer(Driver):
    """Marlin host-protocol driver (see module docstring).

    ``port``: device path, pyserial URL or ``sim://?...``. With ``sim://`` the simulator
    runs in this process and is available as ``printer.simulator``.
    """

    def __init__(self, port, settings=None, on_event=None):
        settings = settings or LinkSettings()
        simulator = None
        if port.startswith("sim://"):
            from hostd.printer.sim import Simulator
            from hostd.printer.simconfig import SimConfig
            simulator = Simulator(SimConfig.from_url(port), baud=settings.baud)
            simulator.start()
        super().__init__(port, settings, on_event, simulator)

    # -- public API (any thread) ---------------------------------------------------------

    @property
    def state(self):
        return self._state

    def connect(self, timeout_s=None):
        """Open the port, handshake, and return when idle; raises PrinterError."""
        if self._thread is None:
            # Published only once started: close() from another thread (a daemon shut
            # down while its printer connects) joins a thread that runs, or none.
            thread = threading.Thread(target=self._run, name="hostd-link", daemon=True)
            thread.start()
            self._thread = thread
            if self._closing:
                self.close()
                raise PrinterError("state", "closed while connecting")
        budget = timeout_s or (self.settings.open_timeout_s + self.settings.reset_wait_s
                               + self.settings.handshake_timeout_s * (self.settings.handshake_attempts + 3))
        return self._call("connect", timeout_s=budget)

    def start(self, source, job_id=None, start_line=1, prelude=()):
        """Start streaming a file path, or an iterable of G-code lines; returns the Job.

        ``start_line`` (1-based, in the file) skips everything before it: with an
        interrupted job's ``last_confirmed_line + 1`` it continues where the firmware
        stopped -- after the caller has re-homed/re-heated as its profile requires.
        ``prelude`` commands go first (the job's feed rate), counted as file line 0.
        """
        job = Job(source, job_id, start_line, prelude)
        return self._call("start", job)

    # pause, resume, cancel, send: see events.Publisher.

    def estop(self):
        """Emergency stop: write M112 now, ahead of everything queued; returns the time sent."""
        port = self._serial
        if port is None:
            raise PrinterError("state", "not connected")
        with self._write_lock:
            try:
                port.write(b"M112\n")
                port.flush()
            except (serial.SerialException, OSError) as exc:
                raise PrinterError("port", "emergency stop could not be written: %s" % exc) from exc
            sent_at = time.monotonic()
        self._inbox.put(("call", "estop", (), None))
        return sent_at

    def close(self):
        """Disconnect and stop the driver thread (and the in-process simulator)."""
        self._closing = True
        if self._thread is not None:
            self._inbox.put(("call", "close", (), None))
            self._thread.join(5)
        self._drop_port()
        if self.simulator is not None:
            self.simulator.stop()
