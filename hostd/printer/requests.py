"""What people and the printer's own controls ask of a link: start, pause, resume, cancel,
send, emergency stop, and Marlin's ``//action:`` host commands.

A mixin of :class:`hostd.printer.driver.Driver`; every method runs on the driver thread.
"""

import serial

from hostd.printer import protocol
from hostd.printer.errors import PortLost, PrinterError
from hostd.printer.job import CANCELLING, ERROR, PAUSED, PAUSING, PRINTING
from hostd.printer.settings import script_lines

DISCONNECTED, CONNECTING, IDLE, HEATING, ERROR_STATE = "disconnected", "connecting", "idle", "heating", "error"
BLOCKING_HEAT = ("M109", "M190", "M191")


class Requests:
    """Request handlers (``_do_<name>``) and the script queue of the driver."""

    def _require_connected(self):
        if self._serial is None or self._state in (DISCONNECTED, CONNECTING, ERROR_STATE):
            raise PrinterError("state", "printer is %s" % self._state)

    def _do_start(self, job):
        self._require_connected()
        if self.job is not None and self.job.result is None:
            raise PrinterError("state", "a job is already running (%s)" % self.job.id)
        self.job = job
        self._set_state(PRINTING)
        self._emit("job", event="started", job=job.snapshot())
        return job

    def _active_job(self):
        job = self.job
        if job is None or job.result is not None:
            raise PrinterError("state", "no job is running")
        return job

    def _do_pause(self):
        job = self._active_job()
        if job.phase == PRINTING:
            job.phase = PAUSING
            self._queue_script("pause", self.settings.pause_gcode)
        return job.phase

    def _do_resume(self):
        job = self._active_job()
        if job.phase in (PAUSING, PAUSED):
            self._queue_script("resume", self.settings.resume_gcode)
            job.phase = PRINTING
            self._set_state(PRINTING)
        return job.phase

    def _do_cancel(self):
        job = self._active_job()
        if job.phase != CANCELLING:
            job.phase = CANCELLING
            self._queue_script("cancel", self.settings.cancel_gcode)
            heating = any(s.command[:4] in BLOCKING_HEAT for s in self._flow.fifo)
            if heating and self.capabilities.get("EMERGENCY_PARSER") and self._serial is not None:
                # M109/M190 would hold the cancel script back until the target is reached;
                # M108 (emergency parser) ends the wait at once, as OctoPrint does.
                with self._write_lock:
                    try:
                        self._serial.write(b"M108\n")
                    except (serial.SerialException, OSError) as exc:
                        raise PortLost("write failed: %s" % exc) from exc
                if not self.capabilities.get("ADVANCED_OK"):
                    self._flow.expect_foreign_ok()   # M108 is answered by a plain ok too
        return job.phase

    def _do_send(self, command):
        self._require_connected()
        command = protocol.clean(command)
        if command:
            self._priority.append((command, ("user",)))

    def _do_estop(self):
        self.last_error = "emergency stop (M112)"
        self._abandon_stream()
        # Without EMERGENCY_PARSER the M112 waits behind the queued commands.
        self._emit("estop", emergency_parser=bool(self.capabilities.get("EMERGENCY_PARSER")))
        self._set_state(ERROR_STATE)
        self._finish_job(ERROR, "emergency stop")

    def _abandon_stream(self):
        """Stop waiting for answers and drop anything queued (the firmware is halted)."""
        self._priority.clear()
        self._flow.abandon()

    def _queue_script(self, name, text):
        for command in script_lines(text):
            self._priority.append((command, ("script", name)))

    def _finish_job(self, result, error=None):
        job = self.job
        if job is not None and job.finish(result, error):
            self._emit("job", event="finished", job=job.snapshot())

    def _on_action(self, reply):
        """The printer's own controls (``//action:``): do what its user asked.

        Marlin leaves a host's print to the host: cancelling or pausing it on the
        printer's screen only sends ``//action:cancel`` or ``pause``, so without this
        the print would go on. ``paused``/``resumed`` say the firmware did it itself
        (a filament change): the feed stops or goes on, without our scripts.
        """
        name = reply.action
        self._emit("action", action=name, text=reply.text)
        job = self.job
        if job is None or job.result is not None:
            return
        if name in ("cancel", "abort"):
            job.cancelled_by = "on the printer"
            self._do_cancel()
        elif name == "pause":
            self._do_pause()
        elif name == "resume":
            self._do_resume()
        elif name == "paused" and job.phase == PRINTING:
            job.phase = PAUSING          # PAUSED once everything sent is answered
        elif name == "resumed" and job.phase in (PAUSING, PAUSED):
            job.phase = PRINTING
            self._set_state(PRINTING)
