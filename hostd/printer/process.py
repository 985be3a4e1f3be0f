"""The driver in its own process: :class:`PrinterProcess`, same interface as ``Printer``.

A thread is not enough to keep CPU-heavy Python work (path planning) from stalling the
stream: every line needs the GIL a couple of times, and with busy Python threads in the
same process each handoff waits up to the switch interval (5 ms). Measured with
``benchmarks/serial.py --cpu-load``: one busy thread already starves the planner at 80 mm/s.
Here the link runs in a child process (spawned, so it inherits no locks or threads) and
the parent keeps a mirror of its state, updated from the events the child forwards.

Differences from ``Printer``: ``start`` takes a path or a list of lines (an iterator is
read into a list first) and returns a :class:`JobProxy`; ``on_event`` runs in the
parent's pipe thread; ``simulator`` is None (``sim://`` runs in the child).
"""

import itertools
import socket
import subprocess
import sys
import threading
from multiprocessing.connection import Connection

from hostd.printer.driver import DISCONNECTED
from hostd.printer.errors import PrinterError
from hostd.printer.events import Event, Publisher
from hostd.printer.settings import LinkSettings
from hostd.printer.temps import TemperatureLog

_CALL_TIMEOUT_S = 30.0


class JobProxy:
    """Parent-side view of a job running in the child (snapshot dict semantics of Job)."""

    def __init__(self, snapshot):
        self._snapshot = snapshot
        self._finished = threading.Event()
        self.id = snapshot["id"]

    def _update(self, snapshot):
        self._snapshot = snapshot
        if snapshot["result"] is not None:
            self._finished.set()

    def snapshot(self):
        return dict(self._snapshot)

    def wait(self, timeout_s=None):
        return self._finished.wait(timeout_s)

    def __getattr__(self, name):
        snapshot = self.__dict__.get("_snapshot") or {}
        if name in snapshot:
            return snapshot[name]
        raise AttributeError(name)


class PrinterProcess(Publisher):
    """``Printer`` running in a child process (see module docstring)."""

    def __init__(self, port, settings=None, on_event=None):
        self.port_url = port
        self.settings = settings or LinkSettings()
        self.on_event = on_event
        self.simulator = None
        self.state = DISCONNECTED
        self.job = None
        self.temperatures = TemperatureLog(self.settings.temp_history)
        self.capabilities, self.firmware_info, self.stats, self.last_error = {}, {}, {}, None
        self._subscribers = []
        self._calls = {}
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        # A fresh interpreter (not multiprocessing's spawn, which re-imports the caller's
        # __main__), talking pickles over a socketpair. In a session of its own: Ctrl-C in
        # the terminal of `hostd run` signals the whole foreground group, and a link that
        # died with it would take the daemon's cancel script (heaters off) with it. It
        # still ends with the daemon: the socket closes, and it closes the printer.
        ours, theirs = socket.socketpair()
        self._process = subprocess.Popen(
            [sys.executable, "-m", "hostd.printer.child", str(theirs.fileno())],
            pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, start_new_session=True)
        theirs.close()
        self._conn = Connection(ours.detach())
        self._conn.send((port, self.settings))
        self._listener = threading.Thread(target=self._listen, name="hostd-link-pipe", daemon=True)
        self._listener.start()

    # -- the Printer interface -------------------------------------------------------------

    def connect(self, timeout_s=None):
        return self._call("connect", timeout_s, timeout_s=(timeout_s or _CALL_TIMEOUT_S) + 5)

    def start(self, source, job_id=None, start_line=1, prelude=()):
        if not isinstance(source, (str, list, tuple)) and not hasattr(source, "__fspath__"):
            source = list(source)
        snapshot = self._call("start", str(source) if hasattr(source, "__fspath__") else source,
                              job_id, start_line, list(prelude))
        with self._lock:
            self.job = JobProxy(snapshot)
        return self.job

    # pause, resume, cancel, send: see events.Publisher.

    def estop(self):
        return self._call("estop")

    @property
    def ended(self):
        """True once the child process is gone (crashed or closed): connect no more."""
        return self._process.poll() is not None

    def close(self):
        if self._process.poll() is None:
            try:
                self._call("close", timeout_s=10)
            except PrinterError:
                pass
        try:
            self._process.wait(10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        self._conn.close()

    # -- plumbing --------------------------------------------------------------------------

    def _call(self, name, *args, timeout_s=_CALL_TIMEOUT_S):
        call_id = next(self._ids)
        waiter = [threading.Event(), None]
        self._calls[call_id] = waiter
        try:
            with self._lock:
                self._conn.send(("call", call_id, name, args))
        except (OSError, EOFError) as exc:
            raise PrinterError("internal", "link process is gone: %s" % exc) from exc
        if not waiter[0].wait(timeout_s):
            self._calls.pop(call_id, None)
            raise PrinterError("timeout", "%s: link process did not answer in %.1f s" % (name, timeout_s))
        kind, value = waiter[1]
        if kind == "error":
            raise PrinterError(*value)
        return value

    def _listen(self):
        while True:
            try:
                message = self._conn.recv()
            except (EOFError, OSError):
                break
            if message[0] in ("result", "error"):
                waiter = self._calls.pop(message[1], None)
                if waiter is not None:
                    waiter[1] = (message[0], message[2])
                    waiter[0].set()
            elif message[0] == "event":
                self._on_event(Event(*message[1]), message[2])
        self.state = DISCONNECTED
        for waiter in list(self._calls.values()):
            waiter[1] = ("error", ("internal", "link process ended"))
            waiter[0].set()
        job = self.job
        if job is not None and job._snapshot["result"] is None:
            job._update(dict(job._snapshot, result="interrupted", interrupted=True,
                             error="link process ended"))

    def _on_event(self, event, mirror):
        self.state = mirror["state"]
        self.capabilities, self.firmware_info = mirror["capabilities"], mirror["firmware"]
        self.stats, self.last_error = mirror["stats"], mirror["last_error"]
        if event.kind == "temperature":
            self.temperatures.update({h: (v["current"], v["target"]) for h, v in mirror["temps"].items()},
                                     event.time)
        job = self.job
        if job is not None and mirror["job"] is not None and mirror["job"]["id"] == job.id:
            job._update(mirror["job"])
        self._publish(event)
