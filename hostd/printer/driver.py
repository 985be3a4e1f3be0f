"""The driver thread behind :class:`hostd.printer.link.Printer`.

All protocol and job state is owned by this one thread: requests from other threads
arrive through ``_inbox`` (as do the reader thread's replies), so nothing here needs a
lock except the port write, which :meth:`Printer.estop` shares.
"""

import queue
import threading
import time
import traceback
from collections import deque
from concurrent.futures import Future

import serial

from hostd.printer import protocol
from hostd.printer.errors import PortLost, PrinterError
from hostd.printer.events import Event, Publisher
from hostd.printer.flow import LineFlow, Sent
from hostd.printer.handshake import handshake
from hostd.printer.job import CANCELLED, CANCELLING, DONE, ERROR, INTERRUPTED
from hostd.printer.job import PAUSED, PAUSING, PRINTING
from hostd.printer.requests import (BLOCKING_HEAT, CONNECTING, DISCONNECTED, ERROR_STATE, HEATING,
                                     IDLE, Requests)
from hostd.printer.temps import TemperatureLog
from hostd.printer.transport import Reader, close_port, open_port

_FATAL_WORDS = ("halted", "kill", "stopped")
# Closing the link during a print runs the cancel script first, for at most this long
# (within Printer.close's 5 s join): heaters off and the head lifted, whatever closed it.
CLOSE_CANCEL_S = 3.0


class Driver(Requests, Publisher):
    """State and thread of the link; :class:`~hostd.printer.link.Printer` is its public face."""

    def __init__(self, port, settings, on_event, simulator):
        self.port_url = port
        self.settings = settings
        self.on_event = on_event
        self.simulator = simulator
        self.temperatures = TemperatureLog(self.settings.temp_history)
        self.capabilities = {}
        self.firmware_info = {}
        self.job = None
        self.last_error = None
        self.stats = dict(lines_sent=0, bytes_sent=0, resends=0, lines_resent=0, timeouts=0,
                          max_in_flight_lines=0, max_in_flight_bytes=0, oks=0)
        self._state = DISCONNECTED
        self._inbox = queue.Queue()
        self._subscribers = []
        self._write_lock = threading.Lock()
        self._serial = None
        self._reader = None
        self._generation = 0
        self._thread = None
        self._closing = False
        self._close_at = None        # closing once the cancel script ran (or at this time)
        self._close_future = None
        self._reconnect_at = None
        self._flow = LineFlow(self.settings, self.stats, 10.0 / self.settings.baud)
        self._reset_stream()

    # -- plumbing ------------------------------------------------------------------------

    def _call(self, name, *args, timeout_s=10.0):
        if self._thread is None:
            raise PrinterError("state", "not connected (call connect() first)")
        future = Future()
        self._inbox.put(("call", name, args, future))
        try:
            return future.result(timeout_s)
        except TimeoutError:
            raise PrinterError("timeout", "%s: driver did not answer in %.1f s" % (name, timeout_s)) from None

    def _emit(self, kind, **data):
        self._publish(Event(kind, data))

    def _set_state(self, state):
        if state != self._state:
            self._state = state
            self._emit("state", state=state)

    def _reset_stream(self):
        """Forget the line-level state (new connection: the firmware starts at N0)."""
        self._flow.reset()
        self._priority = deque()
        self._last_rx = time.monotonic()
        self._timeouts = 0
        self._next_poll = 0.0
        self._last_progress = 0.0

    # -- driver thread -------------------------------------------------------------------

    def _run(self):
        while True:
            now = time.monotonic()
            try:
                item = self._inbox.get(timeout=self._wait_s(now))
            except queue.Empty:
                item = None
            try:
                if self._reconnect_at is not None and time.monotonic() >= self._reconnect_at:
                    self._reconnect()
                if item is not None:
                    if self._dispatch(item) == "close":
                        return
                    # Drain what is already there before writing: cheaper and keeps order.
                    while True:
                        try:
                            item = self._inbox.get_nowait()
                        except queue.Empty:
                            break
                        if self._dispatch(item) == "close":
                            return
                self._tick()
                self._pump()
                if self._close_at is not None and (self.job.result is not None
                                                   or time.monotonic() >= self._close_at):
                    self._dispatch(("call", "close", (), self._close_future))
                    return
            except PortLost as lost:
                self._lost(str(lost))
                if self.settings.reconnect and not self._closing:
                    self._reconnect_at = time.monotonic() + self.settings.reconnect_interval_s
            except Exception as exc:
                # A bug must not kill the thread that owns the printer: stop the job
                # loudly, keep serving (estop, connect) and report it.
                traceback.print_exc()
                self._fatal("internal", "driver error: %r" % exc)

    def _reconnect(self):
        """Try the lost port again (it may have come back under the same name)."""
        self._reconnect_at = None
        if self._state != DISCONNECTED:
            return
        try:
            self._connect()
        except PrinterError as exc:
            self.last_error = str(exc)
            self._reconnect_at = time.monotonic() + self.settings.reconnect_interval_s
            return
        self._emit("connected", reconnected=True)

    def _wait_s(self, now):
        deadlines = [now + 0.5]
        if self._close_at is not None:
            deadlines.append(self._close_at)
        if self._reconnect_at is not None:
            deadlines.append(self._reconnect_at)
        if self._serial is not None:
            if self._flow.awaiting():
                deadlines.append(self._last_rx + self.settings.ok_timeout_s)
            if self._flow.resync_until > now:
                deadlines.append(self._flow.resync_until)
            if self._next_poll and not self.capabilities.get("AUTOREPORT_TEMP"):
                deadlines.append(self._next_poll)
        return max(0.0, min(deadlines) - now)

    def _dispatch(self, item):
        kind = item[0]
        if kind == "call":
            _, name, args, future = item
            if name == "close":
                if self._cancel_before_close(future):
                    return None
                self._drop_port()
                self._set_state(DISCONNECTED)
                self._finish_job(INTERRUPTED, "link closed")
                if future:
                    future.set_result(None)
                return "close"
            try:
                result = getattr(self, "_do_" + name)(*args)
            except PrinterError as exc:
                if future:
                    future.set_exception(exc)
            except PortLost as exc:
                if future:
                    future.set_exception(PrinterError("port", str(exc)))
                raise
            except Exception as exc:
                if future:   # a bug: tell the caller instead of leaving it waiting
                    future.set_exception(PrinterError("internal", "%s failed: %r" % (name, exc)))
                raise
            else:
                if future:
                    future.set_result(result)
        elif item[1] != self._generation:
            return None  # news from a connection we already dropped
        elif kind == "reply":
            self._on_reply(item[2], item[3])
        elif kind == "lost":
            raise PortLost(item[2])
        return None

    def _cancel_before_close(self, future):
        """A print still running when the link closes gets its cancel script first
        (a close in the middle of a print otherwise leaves the heaters on); True while
        that is under way."""
        job = self.job
        if (self._close_at is not None or job is None or job.result is not None
                or self._serial is None or self._state == ERROR_STATE):
            return False
        try:
            self._do_cancel()
        except (PrinterError, PortLost):
            return False
        if job.cancelled_by is None:
            job.cancelled_by = "because the link was closed"
        self._close_at, self._close_future = time.monotonic() + CLOSE_CANCEL_S, future
        return True

    # -- connection ----------------------------------------------------------------------

    def _do_connect(self):
        if self._state not in (DISCONNECTED, ERROR_STATE, IDLE):
            raise PrinterError("state", "cannot connect while %s" % self._state)
        self._connect()
        self._emit("connected", reconnected=False)
        return self.firmware_info

    def _connect(self):
        if self._serial is not None:
            self._drop_port()
            # A board resets when its port is opened; closing and reopening within a
            # blink may not register as a new open (a pty certainly does not).
            time.sleep(self.settings.reopen_delay_s)
        self._reconnect_at = None
        self._set_state(CONNECTING)
        self._reset_stream()
        deadline = time.monotonic() + self.settings.open_timeout_s
        while True:
            try:
                port = open_port(self.port_url, self.settings.baud, self.simulator)
                break
            except PrinterError:
                if time.monotonic() > deadline:
                    self._set_state(DISCONNECTED)
                    raise
                time.sleep(0.1)
        self._generation += 1
        self._serial = port
        self._reader = Reader(port, self._inbox, self._generation)
        self._reader.start()
        try:
            result = handshake(self, port)
        except PrinterError:
            self._drop_port()
            self._set_state(DISCONNECTED)
            raise
        self.capabilities = result.capabilities
        self.firmware_info = result.firmware
        advanced = self.settings.send_ahead and self.capabilities.get("ADVANCED_OK")
        if self.settings.max_in_flight_lines:
            capacity = self.settings.max_in_flight_lines if advanced else 1
        else:
            # An idle Marlin reports B = BUFSIZE - 1 (the answered line still holds a slot).
            capacity = (result.max_buffer_free + 1) if advanced and result.max_buffer_free else 1
        self._flow.reset(result.next_n, capacity)
        for n, data, command in result.sent:
            self._flow.remember(Sent(n, data, command, ("host",)))
        self._last_rx = time.monotonic()
        self._next_poll = time.monotonic()
        self.last_error = None
        self._set_state(IDLE)

    def _drop_port(self):
        port, self._serial = self._serial, None
        if self._reader is not None:
            self._reader.stopping = True
        if port is not None:
            close_port(port)
        self._generation += 1

    def _lost(self, reason):
        """The port failed: the job (if any) is interrupted where it was confirmed."""
        self._drop_port()
        self.last_error = reason
        self._set_state(DISCONNECTED)
        self._finish_job(INTERRUPTED, reason)

    # -- receiving -----------------------------------------------------------------------

    def _on_reply(self, reply, at):
        kind = reply.kind
        # Anything but a periodic temperature report shows the firmware is working on our
        # lines; reports count only while M109/M190 blocks (Marlin prints them instead of
        # busy messages then). Otherwise M155 reports would hide a lost ok for ever.
        if kind != protocol.TEMPS or self._flow.head_command()[:4] in BLOCKING_HEAT:
            self._last_rx = at
        if reply.temps:
            self.temperatures.update(reply.temps, time.time())
            self._emit("temperature", temps=self.temperatures.current())
        if kind == protocol.OK:
            unnumbered = reply.line is None and reply.planner_free is not None
            confirmed = self._flow.on_ok(reply.line, unnumbered)
            if confirmed is not None:
                self._timeouts = 0
                for sent in confirmed:
                    self._confirm(sent)
        elif kind == protocol.RESEND:
            try:
                accepted, honoured = self._flow.on_resend(reply.line, at)
            except PrinterError as exc:
                self._fatal(exc.code, exc.message)
                return
            for sent in accepted:
                self._confirm(sent)
            if honoured:
                if self.job is not None and self.job.result is None:
                    self.job.resends += 1
                self._emit("resend", line=reply.line)
        elif kind == protocol.ERROR:
            if protocol.is_resend_error(reply.text):
                self._flow.on_line_error(at)
            else:
                self._on_firmware_error(reply.text)
        elif kind == protocol.START:
            if self._state not in (CONNECTING, ERROR_STATE):
                raise PortLost("printer reset unexpectedly (got 'start')")
        elif kind == protocol.ACTION:
            self._on_action(reply)
        elif kind in (protocol.ECHO, protocol.OTHER, protocol.FIRMWARE):
            if protocol.is_fragment_echo(reply.text) and not self.capabilities.get("ADVANCED_OK"):
                self._flow.expect_foreign_ok()   # (with ADVANCED_OK its ok lacks N: on_ok knows)
            self._emit("log", text=reply.text)
        # BUSY: a sign of life only (it resets the answer timeout above).

    def _confirm(self, sent):
        job = self.job
        if sent.origin[0] == "job" and job is not None and job.result is None:
            job.confirmed += 1
            job.last_confirmed_line = sent.origin[1]
            job.bytes_confirmed += len(sent.data)

    def _on_firmware_error(self, text):
        self._emit("firmware_error", message=text)
        if self._state == ERROR_STATE:
            return
        self.last_error = text
        self._abandon_stream()
        self._set_state(ERROR_STATE)
        self._finish_job(ERROR, text)
        if not any(word in text.lower() for word in _FATAL_WORDS):
            self._queue_script("error", self.settings.error_gcode)  # it still listens

    def _fatal(self, code, message):
        self.last_error = "%s: %s" % (code, message)
        self._abandon_stream()
        self._set_state(ERROR_STATE)
        self._finish_job(ERROR, message)

    # -- sending -------------------------------------------------------------------------

    def _tick(self):
        """Timers: answer timeout recovery and temperature polling."""
        if self._serial is None:
            return
        now = time.monotonic()
        if self._flow.awaiting() and now - self._last_rx >= self.settings.ok_timeout_s:
            if self._state == ERROR_STATE:
                self._abandon_stream()   # best-effort error script: no recovery games
                return
            self._timeouts += 1
            self.stats["timeouts"] += 1
            self._emit("timeout", count=self._timeouts, in_flight=len(self._flow.fifo))
            if self._timeouts > self.settings.max_timeouts:
                self._fatal("timeout", "printer not responding: no answer for %.1f s, %d recoveries failed"
                            % (self.settings.ok_timeout_s, self._timeouts - 1))
                return
            # OctoPrint's recovery: whatever was in flight lost its answer; probe with a
            # numbered M105 -- accepted means those lines got through, Resend means not.
            self._flow.expire()
            self._priority.appendleft(("M105", ("probe",)))
            self._last_rx = now
        if (self._next_poll and now >= self._next_poll and self._state != ERROR_STATE
                and not self.capabilities.get("AUTOREPORT_TEMP")):
            self._next_poll = now + self.settings.temp_poll_s
            if not any(origin[0] in ("poll", "probe") for _, origin in self._priority):
                self._priority.append(("M105", ("poll",)))

    def _next_line(self):
        """(Sent, is_new) to transmit next, or None."""
        flow = self._flow
        if flow.replaying():
            return flow.replay_line(), False
        if self._priority:
            command, origin = self._priority[0]
        else:
            job = self.job
            if job is None or job.result is not None or job.phase != PRINTING:
                return None
            item = job.peek()
            if item is None:
                return None
            command, origin = item[1], ("job", item[0])
        return flow.new_line(command, origin), True

    def _pump(self):
        """Send as much as flow control allows."""
        flow = self._flow
        if self._serial is not None:
            now = time.monotonic()
            while not flow.window_full(now):
                nxt = self._next_line()
                if nxt is None:
                    break
                sent, new = nxt
                if not flow.fits(sent):
                    break
                if new:
                    if self._priority:
                        self._priority.popleft()
                    else:
                        self.job.take()
                self._transmit(sent, new)
        self._after_progress()

    def _transmit(self, sent, new):
        if not self._flow.fifo:
            self._last_rx = time.monotonic()   # the answer timeout starts with the first line
        self._flow.commit(sent, new)
        with self._write_lock:
            try:
                self._serial.write(sent.data)
            except (serial.SerialException, OSError) as exc:
                raise PortLost("write failed: %s" % exc) from exc
        if self.job is not None and self.job.result is None:
            self.job.bytes_sent += len(sent.data)

    def _after_progress(self):
        """Phase changes that happen once everything sent has been answered."""
        job = self.job
        if job is not None and job.result is None:
            settled = self._flow.settled()
            if job.phase == PRINTING and settled and job.peek() is None:
                self._set_state(IDLE)       # state first: whoever waits on the job sees it
                self._finish_job(DONE)
            elif job.phase == PAUSING and settled:
                job.phase = PAUSED
                self._set_state(PAUSED)
            elif job.phase == CANCELLING and settled:
                self._set_state(IDLE)
                self._finish_job(CANCELLED, job.cancelled_by and "cancelled " + job.cancelled_by)
            elif job.phase == PRINTING and self._state in (PRINTING, HEATING):
                head = self._flow.head_command()[:4]
                self._set_state(HEATING if head in BLOCKING_HEAT else PRINTING)
            now = time.monotonic()
            if job.result is None and now - self._last_progress >= self.settings.progress_interval_s:
                self._last_progress = now
                self._emit("progress", **job.snapshot())
