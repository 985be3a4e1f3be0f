"""One configured printer as the daemon sees it: its link, connected in the background, and
the job printing on it."""

import logging
import threading

log = logging.getLogger("hostd.daemon")


def link_settings(printer_config):
    """The link's settings for one printer: its baud and its profile's scripts, so a
    pause parks, a resume unparks and a cancel runs this printer's own cancel G-code."""
    from hostd.printer import LinkSettings
    from pipeline.profiles.profile import load_profile

    profile = load_profile(printer_config.profile)
    return LinkSettings(baud=printer_config.baud,
                        pause_gcode=profile.render_gcode("pause"),
                        resume_gcode=profile.render_gcode("resume"),
                        cancel_gcode=profile.render_gcode("cancel"))


class Slot:
    """One configured printer: its link (connected in the background) and current job."""

    def __init__(self, config):
        self.config = config
        self.name = config.name
        self.printer = None
        self.job_id = None           # store id of the job printing here
        self.link_job = None         # hostd.printer.process.JobProxy
        self.ending = None           # records a finished print once the store takes it
        self.progress_due = 0.0      # when its progress is next written to the store
        self.paused = False          # operator pause: no new jobs
        # Why the printer waits for a person (a print ended on its bed: finished, cancelled
        # or failed), until one says the bed is clear; None: the bed is known clear.
        self.held = None
        self.clears_bed = False      # the print running ends by taking its part off the bed
        self.error = None
        self._thread = None

    def connect_async(self):
        if self._thread is not None and self._thread.is_alive():
            return
        self._thread = threading.Thread(target=self._connect, name="connect-" + self.name,
                                        daemon=True)
        self._thread.start()

    def _connect(self):
        from hostd.printer import PrinterError, PrinterProcess
        from pipeline.errors import PipelineError
        try:
            if self.printer is not None and self.printer.ended:
                self.printer.close()           # its process died: a new one takes over
                self.printer = None
            if self.printer is None:
                # The link streams from a process of its own: the page's requests, the
                # planner and the run loop take this process's GIL, never the stream's.
                self.printer = PrinterProcess(self.config.port, link_settings(self.config))
            self.printer.connect()
            self.error = None
            log.info("printer %s connected (%s)", self.name, self.config.port)
        except (PrinterError, PipelineError, OSError) as exc:
            self.error = str(exc)
            log.warning("printer %s: cannot connect: %s", self.name, exc)

    @property
    def state(self):
        return self.printer.state if self.printer is not None else "disconnected"

    @property
    def last_error(self):
        """Why the printer is not working (a failed connect, or the link's own error), or
        None while it works."""
        if self.error:
            return self.error
        if self.printer is not None and self.state in ("error", "disconnected"):
            return self.printer.last_error
        return None

    def available(self):
        return self.job_id is None and not self.paused and self.held is None \
            and self.state == "idle"

    def close(self):
        if self.printer is not None:
            self.printer.close()
