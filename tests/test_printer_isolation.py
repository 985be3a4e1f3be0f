"""The daemon's printer links stream from processes of their own: the page's requests (and
the planner, and the run loop) take the daemon's GIL, never the stream's; the page reads
the parent's mirror of the link and asks nothing of the link process."""

import os
import signal

from daemon_helpers import in_process_daemon, tick_until
from hostd.printer import PrinterProcess
from hostd.web.app import create_app


def _connected(d):
    tick_until(d, lambda: d.slots[0].state == "idle", timeout=60, what="the printer to connect")
    return d.slots[0].printer


def test_the_link_streams_in_its_own_process_and_the_page_reads_its_mirror(tmp_path,
                                                                           monkeypatch):
    d = in_process_daemon(tmp_path, 0)
    try:
        printer = _connected(d)
        assert isinstance(printer, PrinterProcess)
        assert printer._process.pid != os.getpid() and printer._process.poll() is None
        tick_until(d, lambda: printer.temperatures.current(), what="a temperature report")

        def no_call(self, name, *args, **kw):
            raise AssertionError("the page called into the link: %s" % name)
        monkeypatch.setattr(PrinterProcess, "_call", no_call)
        client = create_app(d.config, store=d.store, daemon=d).test_client()
        for path in ("/", "/api/status?history=1", "/api/printers", "/metrics", "/api/printer",
                     "/api/job"):
            assert client.get(path).status_code in (200, 409), path
        card = client.get("/api/status").get_json()["printers"][0]
        assert card["link_state"] == "idle" and card["temperatures"]
    finally:
        monkeypatch.undo()
        d.shutdown()


def test_a_link_process_that_died_is_replaced_by_a_new_one(tmp_path, monkeypatch):
    from hostd import printing
    monkeypatch.setattr(printing, "RECONNECT_S", 0.5)   # the loop's retry, not its pace, here
    d = in_process_daemon(tmp_path, 0)
    try:
        first = _connected(d)
        os.kill(first._process.pid, signal.SIGKILL)
        tick_until(d, lambda: d.slots[0].printer is not first and d.slots[0].state == "idle",
                   timeout=60, what="a new link process")
        assert first.ended and not d.slots[0].printer.ended
    finally:
        d.shutdown()


def test_closing_a_link_process_that_is_still_connecting_does_not_wait_for_the_connect():
    """A printer that never answers takes a connect its whole budget (here about 70 s); a daemon
    stopping meanwhile closes its link at once, as with a thread-based link."""
    import pty
    import threading
    import time

    from hostd.printer import LinkSettings, PrinterError
    ours, theirs = pty.openpty()          # a port that opens and never says a word
    try:
        printer = PrinterProcess(os.ttyname(theirs), LinkSettings(reconnect=False,
                                                                  handshake_timeout_s=10.0))
        failed = []

        def connect():
            try:
                printer.connect()
            except PrinterError as exc:
                failed.append(exc)
        thread = threading.Thread(target=connect, daemon=True)
        thread.start()
        time.sleep(1.0)                   # inside the handshake
        closer = threading.Thread(target=printer.close, daemon=True)
        closer.start()
        closer.join(12)
        assert not closer.is_alive() and printer.ended, "close waited for the connect"
        thread.join(12)
        assert failed
    finally:
        os.close(ours)
        os.close(theirs)
