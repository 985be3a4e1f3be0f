"""Entry point of the link's child process (see :mod:`hostd.printer.process`).

``python -m hostd.printer.child FD``: a thread-based Printer driven over the socket FD.
"""

import os
import sys
import threading
from multiprocessing.connection import Connection

from hostd.printer.errors import PrinterError


def _child_main(conn):
    """Child process: a thread-based Printer, driven through the pipe."""
    from hostd.printer.link import Printer

    port, settings = conn.recv()
    send_lock = threading.Lock()

    def forward(event):
        job = printer.job
        stats = dict(printer.stats)
        if printer.simulator is not None:    # sim:// runs here: its planner's starvation too
            stats["starvation_s"] = printer.simulator.firmware.stats.get("starvation_s")
        mirror = dict(state=printer.state, job=job.snapshot() if job else None,
                      temps=printer.temperatures.current(), stats=stats,
                      capabilities=dict(printer.capabilities), firmware=dict(printer.firmware_info),
                      last_error=printer.last_error)
        with send_lock:
            try:
                conn.send(("event", (event.kind, event.data, event.time), mirror))
            except (OSError, EOFError):
                pass

    printer = Printer(port, settings, on_event=forward)

    def answer(call_id, name, args):
        try:
            if name == "close":
                printer.close()
                value = None
            elif name == "start":
                value = printer.start(*args).snapshot()
            else:
                value = getattr(printer, name)(*args)
            reply = ("result", call_id, value)
        except PrinterError as exc:
            reply = ("error", call_id, (exc.code, exc.message))
        except Exception as exc:  # a bug: report it to the caller rather than hang it
            reply = ("error", call_id, ("internal", "%s failed: %r" % (name, exc)))
        if call_id is not None:
            with send_lock:
                try:
                    conn.send(reply)
                except (OSError, EOFError):
                    pass

    while True:
        try:
            _, call_id, name, args = conn.recv()
        except (EOFError, OSError):
            name, call_id, args = "close", None, ()
        if name == "close":
            answer(call_id, name, args)
            return
        # Each call waits in a thread of its own, as callers of a thread-based Printer do:
        # a connect that takes its full budget must not hold back a close or an estop.
        threading.Thread(target=answer, args=(call_id, name, args), daemon=True,
                         name="hostd-call-" + name).start()


if __name__ == "__main__":
    try:
        os.nice(-5)   # ahead of the planner when allowed (root); harmless otherwise
    except OSError:
        pass
    _child_main(Connection(int(sys.argv[1])))
