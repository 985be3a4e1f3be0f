"""systemd's watchdog, fed from its own thread: a run loop stuck on a share ends no print.

A network share that stops answering (an NFS server rebooting, hard-mounted as is the
default) blocks every call on it, and the run loop calls it: scanning the drop folder,
renewing the lease, filing an input. Pinging from the loop then stops, and after
``WatchdogSec`` systemd kills hostd and with it every print on the node, although the
prints read local copies and would have gone on, and a restart brings no share back.

So the pings come from here: while the loop has ticked within ``STALL_S`` or a printer
holds a job (printing: its link lives in its own process; or ended, its outcome not yet
recorded, which a restart would turn into "interrupted"), systemd hears that hostd is
alive. A loop stuck with nothing held is left to the watchdog: a restart costs nothing.
A stuck loop (or one failing at every round) is told once, with where it is, and shown as
the node's problem.
"""

import logging
import os
import sys
import threading
import time

log = logging.getLogger("hostd.daemon")
STALL_S = 30.0      # the loop has not ticked for this long: it is stuck
OWN = (os.path.dirname(os.path.abspath(__file__)),
       os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "pipeline"))


def where(thread_id):
    """The innermost frame of our own code in thread ``thread_id``: "file.py:line in f"."""
    frame = sys._current_frames().get(thread_id)
    while frame is not None:
        if os.path.abspath(frame.f_code.co_filename).startswith(OWN):
            return "%s:%d in %s" % (os.path.basename(frame.f_code.co_filename), frame.f_lineno,
                                    frame.f_code.co_name)
        frame = frame.f_back
    return "?"


class LoopWatch:
    """Feed systemd's watchdog while the run loop moves or a print runs.

    notify : :class:`hostd.notify.Notifier`; holding : callable, True while a printer holds
    a job;
    interval_s : seconds between pings (systemd wants one every half of ``WatchdogSec``).
    The loop calls :meth:`tick` at the end of every round it completes.
    """

    def __init__(self, notify, holding, interval_s, clock=time.monotonic):
        self.notify = notify
        self.holding = holding
        self.interval_s = float(interval_s)
        self.clock = clock
        self.last_tick = clock()
        self.problem = None
        self._loop_thread = threading.get_ident()
        self._stop = threading.Event()
        self._thread = None

    def tick(self):
        self.last_tick = self.clock()
        self._loop_thread = threading.get_ident()

    def start(self):
        self._thread = threading.Thread(target=self._run, name="hostd-watchdog", daemon=True)
        self._thread.start()

    def stop(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)

    def check(self):
        """One look: ping if alive, tell when the loop gets stuck or moves again."""
        stuck_s = self.clock() - self.last_tick
        if stuck_s < STALL_S:
            if self.problem is not None:
                log.info("the run loop moves again after %.0f s; carrying on", stuck_s)
                self.problem = None
            self.notify.watchdog()
            return
        if self.problem is None:
            self.problem = ("the run loop has not completed a round since %s (now at %s): a "
                            "network share that does not answer does this, or an error "
                            "repeated in the log" % (
                                time.strftime("%H:%M:%S", time.localtime(time.time() - stuck_s)),
                                where(self._loop_thread)))
            log.error("%s. Prints already running go on (they read local copies) and systemd's "
                      "watchdog is fed while they do; nothing is taken or started until the "
                      "loop moves. Fix: check the shares' mounts and the file server.",
                      self.problem)
        if self.holding():
            self.notify.watchdog()

    def _run(self):
        while not self._stop.wait(self.interval_s):
            try:
                self.check()
            except Exception:   # never let the watchdog's thread die quietly
                log.exception("watchdog check failed")
