"""Opening files other people can write (a drop folder, a share): regular files only.

An ``open`` of a FIFO blocks until someone writes to it, and a read of ``/dev/zero`` never
ends: a planted name would freeze whatever reads it. :func:`opener` opens without
blocking and without following a last symlink, then checks what it opened.
"""

import errno
import os
import stat


class NotRegular(OSError):
    """What was opened is a FIFO, a device, a folder or a symbolic link."""


def opener(path, flags):
    """An ``open(..., opener=opener)``: a descriptor of the regular file ``path`` (a
    symlink to one is followed: ``hostd plan`` is given links), else :class:`NotRegular`
    (or the open's own OSError)."""
    return _open(path, flags)


def opener_nofollow(path, flags):
    """:func:`opener` refusing a symlink as the last component (a shared folder's files)."""
    return _open(path, flags | os.O_NOFOLLOW)


def _open(path, flags):
    try:
        fd = os.open(path, flags | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise NotRegular(errno.ELOOP, "a symbolic link (never followed here)",
                             os.fsdecode(path)) from None
        raise
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise NotRegular(errno.EINVAL, "not a regular file (a FIFO, device or folder)",
                             os.fsdecode(path))
        # A regular file never blocks; the flag would only surprise a later reader.
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def open_regular(path, follow=True):
    """``path`` opened for reading in binary, if it is a regular file (else OSError)."""
    return open(path, "rb", opener=opener if follow else opener_nofollow)
