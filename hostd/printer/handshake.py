"""Connecting to a Marlin board: survive its reset, set line numbers, read capabilities.

Runs in the driver thread right after the port opens, reading the driver's inbox
directly. Requests from other threads that arrive meanwhile are put back afterwards.
"""

import time
from dataclasses import dataclass, field

from hostd.printer import protocol
from hostd.printer.errors import PrinterError

DRAIN_QUIET_S = 0.2    # before retrying a handshake step


@dataclass
class HandshakeResult:
    firmware: dict = field(default_factory=dict)
    capabilities: dict = field(default_factory=dict)
    max_buffer_free: int = 0     # largest ``B`` seen in an ok (idle queue minus one)
    next_n: int = 1
    sent: list = field(default_factory=list)   # (n, wire bytes, command) of numbered lines


class _Session:
    def __init__(self, link, port):
        self.link = link
        self.port = port
        self.deferred = []
        self.result = HandshakeResult()

    def get(self, timeout_s):
        """Next reply of this connection within ``timeout_s`` (None when none came)."""
        deadline = time.monotonic() + max(0.0, timeout_s)
        while True:
            remaining = deadline - time.monotonic()
            try:
                item = self.link._inbox.get(timeout=max(0.0, remaining))
            except Exception:
                return None
            if item[0] == "call":
                self.deferred.append(item)
                if item[1] == "close":   # closing while the board boots: stop waiting for it
                    raise PrinterError("state", "closed while connecting")
                continue
            if item[1] != self.link._generation:
                continue
            if item[0] == "lost":
                raise PrinterError("port", item[2])
            reply = item[2]
            if reply.temps:
                self.link.temperatures.update(reply.temps, time.time())
            if reply.buffer_free is not None:
                self.result.max_buffer_free = max(self.result.max_buffer_free, reply.buffer_free)
            return reply

    def write(self, data):
        with self.link._write_lock:
            try:
                self.port.write(data)
            except Exception as exc:
                raise PrinterError("port", "write failed: %s" % exc) from exc

    def wait_for_boot(self, timeout_s, quiet_s):
        """Wait for ``start`` (the board resets on open); return early on other signs of life."""
        deadline = time.monotonic() + timeout_s
        started = False
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return started
            reply = self.get(remaining)
            if reply is None:
                continue
            if reply.kind == protocol.START:
                started = True
            elif not started:
                return False      # something else talks: the board did not reset
            deadline = time.monotonic() + quiet_s if started else deadline

    def drain(self, quiet_s=DRAIN_QUIET_S):
        """Discard replies until the board has been quiet for ``quiet_s``.

        Before a retry: a late answer to the failed attempt would otherwise be taken for
        the answer to the next line, and every later ok would be off by one.
        """
        while self.get(quiet_s) is not None:
            pass

    def request(self, n, command, timeout_s):
        """Send line ``n`` and collect replies until its ok; None on timeout.

        Raises _Reset when the board announces a reset meanwhile.
        """
        data = protocol.frame(n, command)
        self.write(data)
        self.result.sent.append((n, data, command))
        replies = []
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self.get(deadline - time.monotonic())
            if reply is None:
                if time.monotonic() >= deadline:
                    return None
                continue
            if reply.kind == protocol.START:
                raise _Reset()
            if reply.kind == protocol.RESEND:
                self.drain()           # the ok that follows must not leak into the stream
                return None            # it disagrees about the line: start over
            if reply.kind == protocol.ERROR and not protocol.is_resend_error(reply.text):
                raise PrinterError("firmware", reply.text)
            replies.append(reply)
            if reply.kind == protocol.OK:
                return replies


class _Reset(Exception):
    pass


def handshake(link, port):
    """Bring a freshly opened port to a known state; return a :class:`HandshakeResult`."""
    settings = link.settings
    session = _Session(link, port)
    try:
        return _handshake(session, settings)
    finally:
        for item in session.deferred:
            link._inbox.put(item)


def _handshake(session, settings):
    session.wait_for_boot(settings.reset_wait_s, settings.banner_quiet_s)
    for attempt in range(settings.handshake_attempts):
        session.result.sent.clear()
        try:
            # The numbered M110 sets the firmware's line counter whatever it was.
            if session.request(0, "M110 N0", settings.handshake_timeout_s) is None:
                session.drain()
                continue
            replies = session.request(1, "M115", settings.handshake_timeout_s)
            if replies is None:
                session.drain()
                continue
        except _Reset:
            session.wait_for_boot(settings.reset_wait_s, settings.banner_quiet_s)
            continue
        result = session.result
        for reply in replies:
            if reply.kind == protocol.FIRMWARE:
                result.firmware = protocol.parse_firmware_info(reply.text)
            elif reply.kind == protocol.CAP:
                result.capabilities[reply.cap[0]] = reply.cap[1]
        result.next_n = 2
        if result.capabilities.get("AUTOREPORT_TEMP") and settings.autoreport_s:
            try:
                ok = session.request(2, "M155 S%d" % settings.autoreport_s, settings.handshake_timeout_s)
            except _Reset:
                continue
            if ok is None:
                session.drain()
                continue
            result.next_n = 3
        return result
    raise PrinterError("handshake", "no answer to M110/M115 after %d attempts (wrong port or baud?)"
                       % settings.handshake_attempts)
