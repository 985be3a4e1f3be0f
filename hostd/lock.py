"""One daemon per state folder: ``state_dir/hostd.pid`` held with flock while it runs.

The kernel drops the lock when the process dies, however it dies, so a power cut or
a kill -9 never leaves a stale lock behind; the pid in the file is only for messages.
"""

import fcntl
import os
from pathlib import Path

from hostd.errors import HostdError


class DaemonLock:
    """``state_dir/hostd.pid`` held with flock while a daemon runs (one per state folder)."""

    def __init__(self, path):
        self.path = Path(path)
        self.fd = None

    def acquire(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise HostdError("another hostd (pid %s) already runs with this state folder"
                             % (running_pid(self.path) or "?"), code="daemon.running",
                             file=self.path, fix="stop it first, or give this one its own "
                                                 "state_dir") from None
        os.ftruncate(fd, 0)
        os.write(fd, b"%d\n" % os.getpid())
        self.fd = fd

    def release(self):
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def running_pid(lock_path):
    """The pid of the daemon holding ``lock_path``, or None when no daemon runs."""
    try:
        fd = os.open(lock_path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None          # nobody holds it
    except OSError:
        text = os.read(fd, 32).decode(errors="replace").strip()
        return int(text) if text.isdigit() else -1
    finally:
        os.close(fd)
