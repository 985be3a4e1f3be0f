"""A print job as the link streams it: its command source and its progress."""

import itertools
import os
import threading
import time
import uuid

from hostd.printer.errors import PrinterError
from hostd.printer.protocol import clean

# Job phases (inside the link) and results.
PRINTING, PAUSING, PAUSED, CANCELLING, FINISHED = "printing", "pausing", "paused", "cancelling", "finished"
DONE, CANCELLED, ERROR, INTERRUPTED = "done", "cancelled", "error", "interrupted"


def _numbered(lines):
    """(file line number from 1, command) for every line that has something to send."""
    for number, raw in enumerate(lines, 1):
        command = clean(raw)
        if command:
            yield number, command


def open_source(source, start_line=1):
    """Return (iterator of (file line, command), total commands or None, name).

    Commands on file lines before ``start_line`` are left out (and not counted).
    """
    if start_line > 1:
        lines, _, name = open_source(source)
        skipped = ((n, c) for n, c in lines if n >= start_line)
        total = None
        if isinstance(source, (list, tuple)):
            total = sum(1 for n, _ in _numbered(source) if n >= start_line)
        elif isinstance(source, (str, os.PathLike)):
            with open(os.fspath(source), encoding="ascii", errors="replace") as handle:
                total = sum(1 for n, _ in _numbered(handle) if n >= start_line)
        return skipped, total, "%s from line %d" % (name, start_line)
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        try:
            with open(path, encoding="ascii", errors="replace") as handle:
                total = sum(1 for _ in _numbered(handle))
        except OSError as exc:
            raise PrinterError("config", "cannot read %s: %s" % (path, exc)) from exc

        def read():
            with open(path, encoding="ascii", errors="replace") as handle:
                yield from _numbered(handle)
        return read(), total, path
    if isinstance(source, (list, tuple)):
        total = sum(1 for _ in _numbered(source))
        return _numbered(source), total, "<%d lines>" % len(source)
    return _numbered(source), None, "<stream>"


class Job:
    """One job: what to send and how far the firmware has confirmed it.

    Counters are updated by the driver thread; read them through :meth:`snapshot`.
    ``last_confirmed_line`` is the 1-based line number *in the file* of the last command
    the firmware acknowledged -- where an interrupted print can be resumed from.
    """

    def __init__(self, source, job_id=None, start_line=1, prelude=()):
        lines, total, self.name = open_source(source, start_line)
        # Commands for this job before the file's own (its feed rate): file line 0.
        head = [(0, c) for c in map(clean, prelude) if c]
        self._lines = itertools.chain(head, lines) if head else lines
        self.total = total + len(head) if total is not None else None
        self.id = job_id or uuid.uuid4().hex[:12]
        self.phase = PRINTING
        self.result = None
        self.error = None
        self.cancelled_by = None      # who cancelled, when not the host's own caller
        self.interrupted = False
        self.sent = 0                 # file commands handed to the link (first time)
        self.confirmed = 0            # file commands acknowledged by the firmware
        self.last_confirmed_line = 0
        self.bytes_sent = 0           # wire bytes during the job (resends and scripts too)
        self.bytes_confirmed = 0      # wire bytes of the confirmed file commands
        self.resends = 0
        self.started_at = time.time()
        self.started_mono = time.monotonic()
        self.finished_mono = None
        self.exhausted = False
        self._peeked = None
        self._finished = threading.Event()

    def peek(self):
        """The next (file line, command) without consuming it, or None at the end."""
        if self._peeked is None and not self.exhausted:
            self._peeked = next(self._lines, None)
            if self._peeked is None:
                self.exhausted = True
        return self._peeked

    def take(self):
        item, self._peeked = self._peeked, None
        self.sent += 1
        return item

    def finish(self, result, error=None):
        if self.result is not None:
            return False
        self.result = result
        self.error = error
        self.interrupted = result == INTERRUPTED
        self.phase = FINISHED
        self.finished_mono = time.monotonic()
        if hasattr(self._lines, "close"):
            self._lines.close()
        self._finished.set()
        return True

    def wait(self, timeout_s=None):
        return self._finished.wait(timeout_s)

    @property
    def seconds(self):
        end = self.finished_mono if self.finished_mono is not None else time.monotonic()
        return end - self.started_mono

    def snapshot(self):
        return dict(id=self.id, name=self.name, phase=self.phase, result=self.result,
                    error=self.error, interrupted=self.interrupted, total=self.total,
                    sent=self.sent, confirmed=self.confirmed,
                    last_confirmed_line=self.last_confirmed_line, bytes_sent=self.bytes_sent,
                    bytes_confirmed=self.bytes_confirmed, resends=self.resends,
                    seconds=self.seconds, started_at=self.started_at)


