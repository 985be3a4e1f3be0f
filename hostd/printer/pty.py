"""Pseudo-terminal endpoint for the simulator: the firmware side of a fake serial port.

The host opens the slave path like any serial device (pyserial sets it raw). We close our
own copy of the slave so that the master reports POLLHUP whenever no host has the port
open: that is how the simulator sees the port being opened (and "resets the board", as
an Arduino does when DTR toggles on open) and closed.
"""

import errno
import os
import select
import tty

from hostd.printer.errors import PrinterError


class PtyEndpoint:
    """Master side of a pty, optionally published under a stable symlink."""

    def __init__(self, link_path=None):
        self.link_path = link_path
        self.master = None
        self.path = None
        self._poll = None

    def open(self):
        master, slave = os.openpty()
        # Raw before anyone opens it: otherwise the line discipline echoes our replies
        # back to us as if the host had sent them.
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(master, False)
        self.master = master
        self._poll = select.poll()
        self._poll.register(master, select.POLLIN | select.POLLHUP | select.POLLERR)
        if self.link_path:
            self._publish()
        return self.path

    def _publish(self):
        tmp = "%s.%d.tmp" % (self.link_path, os.getpid())
        try:
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(self.path, tmp)
            os.replace(tmp, self.link_path)  # atomic: a host never sees a missing link
        except OSError as exc:
            raise PrinterError("port", "cannot create link %s: %s" % (self.link_path, exc)) from exc

    def close(self, unlink=True):
        if self.master is not None:
            os.close(self.master)
            self.master = None
        if unlink and self.link_path and os.path.islink(self.link_path):
            try:
                os.unlink(self.link_path)
            except OSError:
                pass

    def poll(self, timeout_s):
        """Return (host_present, readable) after waiting at most ``timeout_s``."""
        if timeout_s > 0:
            # select() has microsecond resolution; poll() only milliseconds, which would
            # add up to a millisecond to every simulated round trip.
            select.select([self.master], [], [], timeout_s)
        events = self._poll.poll(0)
        flags = 0
        for _, ev in events:
            flags |= ev
        return not flags & select.POLLHUP, bool(flags & select.POLLIN)

    def read(self):
        try:
            return os.read(self.master, 65536)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EIO):
                return b""
            raise

    def write(self, data):
        """Write what the pty accepts; return the number of bytes dropped (host not reading)."""
        try:
            return len(data) - os.write(self.master, data)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EIO):
                return len(data)
            raise
