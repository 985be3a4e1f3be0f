"""Opening ports and reading replies: the byte-level side of the link.

Ports: device paths (``/dev/ttyUSB0``, ``/dev/serial/by-id/..``), pyserial URLs
(``socket://host:port`` for ser2net-style servers, ``rfc2217://host:port``) and
``sim://?options`` for the built-in simulator (see :mod:`hostd.printer.simconfig`).
"""

import errno
import threading
import time

import serial

from hostd.printer import protocol
from hostd.printer.errors import PrinterError

READ_TIMEOUT_S = 0.1
WRITE_TIMEOUT_S = 5.0
MAX_PARTIAL_BYTES = 4096   # noise without a newline is dropped beyond this


def open_port(url, baud, simulator=None):
    """Open ``url`` (or the simulator's current pty) and return a pyserial object."""
    target = url
    if url.startswith("sim://"):
        target = simulator.wait_port()
    # A device is held exclusively (flock), so a second program, or a second printer
    # entry naming the same port, is refused instead of mixing its lines into ours.
    exclusive = "://" not in target or None
    try:
        port = serial.serial_for_url(target, baudrate=baud, timeout=READ_TIMEOUT_S,
                                     write_timeout=WRITE_TIMEOUT_S, exclusive=exclusive)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise PrinterError("port", "cannot open %s: %s%s" % (url, exc, _open_fix(exc))) from exc
    return port


def _open_fix(exc):
    """What to do about the usual reasons a printer's port does not open."""
    code = getattr(exc, "errno", None)
    if code == errno.EACCES or "Permission denied" in str(exc):
        return (". Fix: serial ports belong to the group dialout: add this user to it "
                "(sudo usermod -aG dialout $USER, then log in again); the systemd unit does "
                "this with SupplementaryGroups=dialout")
    if code in (errno.EBUSY, errno.EAGAIN) or "exclusively lock" in str(exc):
        return (". Fix: another program holds the port (another hostd or printer entry, "
                "OctoPrint, a slicer, ModemManager): stop it or give each printer its own port")
    return ""


def close_port(port):
    """Close without raising: the port may already be gone (unplugged)."""
    try:
        if hasattr(port, "cancel_read"):
            port.cancel_read()
    except Exception:
        pass
    try:
        port.close()
    except Exception:
        pass


class Reader(threading.Thread):
    """Reads lines from the port and posts ``("reply", generation, Reply, time)`` to ``inbox``.

    On a read failure it posts ``("lost", generation, reason)`` once and ends; the
    generation lets the driver ignore news from a connection it has already dropped.
    """

    def __init__(self, port, inbox, generation):
        super().__init__(name="hostd-link-reader", daemon=True)
        self.port = port
        self.inbox = inbox
        self.generation = generation
        self.stopping = False

    def run(self):
        partial = bytearray()
        port = self.port
        while not self.stopping:
            try:
                waiting = port.in_waiting
                data = port.read(waiting or 1)
            # pyserial's own errors, and what its handlers raise on a port closed
            # under the read: TypeError/AttributeError (posix), ValueError (a
            # socket:// port whose descriptor is already -1).
            except (serial.SerialException, OSError, TypeError, AttributeError, ValueError) as exc:
                if not self.stopping:
                    self.inbox.put(("lost", self.generation, "port lost: %s" % exc))
                return
            if not data:
                continue
            partial += data
            now = time.monotonic()
            while True:
                cut = partial.find(b"\n")
                if cut < 0:
                    break
                raw = bytes(partial[:cut])
                del partial[:cut + 1]
                if raw.strip():
                    self.inbox.put(("reply", self.generation, protocol.parse_reply(raw), now))
            if len(partial) > MAX_PARTIAL_BYTES:
                partial.clear()
