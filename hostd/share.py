"""Every file hostd reads from the share goes through here: regular files only, and
never more than a stated number of bytes.

Whoever can write the share can plant a FIFO (an open blocks until someone writes to
it), a symlink to ``/dev/zero`` (a read never ends) or a file of gigabytes where hostd
expects a few lines. Each read here opens without blocking, checks on the open
descriptor that it holds a regular file, and stops at its limit. What is refused is
the file's fault, not the share's: a :class:`~hostd.errors.HostdError` with code
``share.not_regular`` or ``share.too_large``, never an OSError (which the daemon
takes as the share failing, and stops taking work).
"""

import hashlib
import json
import os
import shutil

from hostd.errors import HostdError
from pipeline.input.regular import NotRegular, open_regular

NOT_REGULAR = "share.not_regular"
TOO_LARGE = "share.too_large"
# A node status file, a lease, a plan's result or stage: a few hundred bytes each.
SMALL_BYTES = 64 * 1024
# A plan's report: some hundred kB with every warning of a large part.
REPORT_BYTES = 16 * 1024 * 1024
CHUNK = 1 << 20


def open_file(path):
    """``path`` opened for binary reading if it is a regular file (else a HostdError;
    an OSError only for the share's own failures, or the file being gone)."""
    try:
        return open_regular(path, follow=False)
    except NotRegular as exc:
        raise HostdError("%s: refused" % exc.strerror, code=NOT_REGULAR, file=path,
                         fix="only regular files belong here; remove it") from None


def read_bytes(path, limit=SMALL_BYTES):
    """The whole of the regular file ``path``, refused past ``limit`` bytes."""
    with open_file(path) as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        raise HostdError("larger than the %d bytes such a file may have" % limit,
                         code=TOO_LARGE, file=path, fix="remove it, or put it back as hostd "
                         "wrote it")
    return data


def read_json(path, limit=SMALL_BYTES):
    """The JSON in ``path`` (ValueError when it is not JSON, HostdError when refused)."""
    return json.loads(read_bytes(path, limit))


def refused(exc):
    """Whether ``exc`` is a file refused here (the file's fault, not the share's)."""
    return isinstance(exc, HostdError) and exc.code in (NOT_REGULAR, TOO_LARGE)


def file_hash(path):
    """sha256 hex digest of the regular file ``path`` (a finite file: read to its end)."""
    h = hashlib.sha256()
    with open_file(path) as f:
        for block in iter(lambda: f.read(CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def copy_out(src, dest):
    """Copy the regular file ``src`` to ``dest`` (a new file, or replaced)."""
    with open_file(src) as f, open(dest, "wb") as out:
        shutil.copyfileobj(f, out, CHUNK)


def mtime(f):
    """The modification time of an open file (an open, not a stat: NFS revalidates)."""
    return os.fstat(f.fileno()).st_mtime
