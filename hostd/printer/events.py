"""Events and the parts of the interface shared by ``Printer`` and ``PrinterProcess``."""

import queue
import time
import traceback
from dataclasses import dataclass, field


@dataclass
class Event:
    """Something the daemon may want to know: ``kind`` plus data (see hostd.printer.link)."""

    kind: str
    data: dict = field(default_factory=dict)
    time: float = field(default_factory=time.time)


class Publisher:
    """Event delivery (callback + subscriber queues), job waiting and the job controls.

    Subclasses set ``on_event``, ``_subscribers`` (a list) and ``job``, and implement
    ``_call(name, *args)``: run request ``name`` where the link lives and return its result.
    """

    def pause(self):
        """Stop feeding the job, then run the pause (park) script; heaters stay on."""
        return self._call("pause")

    def resume(self):
        """Run the resume (unpark) script, then continue with the exact next job line."""
        return self._call("resume")

    def cancel(self):
        """Stop feeding the job, then run the cancel script (heaters off, lift, motors off)."""
        return self._call("cancel")

    def send(self, command):
        """Queue one out-of-band command (console); it goes before further job lines."""
        return self._call("send", command)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def subscribe(self, maxsize=10000):
        """A queue receiving every Event from now on (oldest dropped when full)."""
        events = queue.Queue(maxsize)
        self._subscribers.append(events)
        return events

    def wait(self, timeout_s=None):
        """Wait for the current job to finish; returns its snapshot (None on timeout)."""
        job = self.job
        if job is None:
            return None
        return job.snapshot() if job.wait(timeout_s) else None

    def progress(self):
        """Job progress: confirmed/total lines and bytes (empty dict without a job)."""
        job = self.job
        return job.snapshot() if job else {}

    def _publish(self, event):
        if self.on_event is not None:
            try:
                self.on_event(event)
            except Exception:
                # The listener's bug must not stop the print: report it and carry on.
                traceback.print_exc()
        for events in self._subscribers:
            try:
                events.put_nowait(event)
            except queue.Full:
                try:
                    events.get_nowait()
                    events.put_nowait(event)
                except (queue.Empty, queue.Full):
                    pass
