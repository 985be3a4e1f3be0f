"""sd_notify: tell systemd we are ready, alive and what we are doing (no dependency).

Messages are datagrams on the AF_UNIX socket named by ``$NOTIFY_SOCKET`` (a path, or
``@name`` for the abstract namespace). Without that variable every call is a no-op, so
the daemon runs the same under systemd, in a terminal and in tests.
"""

import os
import socket


class Notifier:
    """Send ``READY=1``, ``STATUS=...``, ``WATCHDOG=1``, ``STOPPING=1``."""

    def __init__(self, address=None):
        address = address if address is not None else os.environ.get("NOTIFY_SOCKET")
        self.address = None
        if address:
            # '@' marks the abstract namespace; the kernel wants a leading NUL instead.
            self.address = "\0" + address[1:] if address.startswith("@") else address
        self.watchdog_s = watchdog_interval_s()

    @property
    def enabled(self):
        return self.address is not None

    def send(self, *assignments):
        """Send one datagram of ``KEY=value`` lines; False if there is nowhere to send."""
        if not self.enabled:
            return False
        payload = "\n".join(assignments).encode("utf-8", "replace")
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
                sock.connect(self.address)
                sock.sendall(payload)
            return True
        except OSError:
            # systemd went away or the socket is not ours: never let this stop a print.
            return False

    def ready(self, status=None):
        return self.send("READY=1", *(["STATUS=" + status] if status else []))

    def status(self, text):
        return self.send("STATUS=" + text.replace("\n", " "))

    def watchdog(self):
        return self.send("WATCHDOG=1")

    def stopping(self, status=None):
        return self.send("STOPPING=1", *(["STATUS=" + status] if status else []))


def watchdog_interval_s():
    """Half of ``$WATCHDOG_USEC`` in seconds (when it is meant for us), else None."""
    usec = os.environ.get("WATCHDOG_USEC")
    pid = os.environ.get("WATCHDOG_PID")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    try:
        return int(usec) / 2e6
    except ValueError:
        return None
