"""Uploads into the drop folder: written under hidden names, checked, renamed sidecar first.

Both doors for uploads (hostd's ``/api/upload`` and OctoPrint's ``/api/files/local``)
store through :func:`store`, so the watcher never sees a half-written input, an input
without its sidecar, or a part left behind after a failed or abandoned request.
"""

import errno
import os
import secrets
from pathlib import Path

from hostd.farm import unique_path


def store(abandoned, folder, name, upload, sidecar=None, check=None):
    """Write an upload (and its sidecar) into ``folder`` under ``name`` or a free variant.

    abandoned : threading.Event, set when the request gave up waiting for the share (the
        parts are then removed rather than renamed)
    upload : werkzeug FileStorage of the input
    sidecar : FileStorage or bytes of the sidecar's YAML, or None
    check : callable(input_part, sidecar_part_or_None) -> None or the PipelineError that
        refuses the upload, run on the written parts before they are renamed

    Returns the input's path, check's refusal, or the OSError. Runs on the share helper.
    """
    tag = ".upload-%s-" % secrets.token_hex(4)
    parts = []
    try:
        folder.mkdir(parents=True, exist_ok=True)
        dest = _free_name(folder, name)
        tmp = folder / (tag + dest.name)
        parts.append(tmp)
        upload.save(str(tmp))
        side_tmp = None
        if _has(sidecar):
            side_tmp = folder / (tag + dest.stem + ".yaml")
            parts.append(side_tmp)
            _write(side_tmp, sidecar)
        refused = check(tmp, side_tmp) if check is not None else None
        if refused is not None:
            return refused
        if abandoned.is_set():
            raise OSError(errno.ETIMEDOUT, "the request gave up waiting for the share")
        if side_tmp is not None:    # sidecar first: the watcher never sees the input alone
            os.rename(side_tmp, dest.with_name(dest.stem + ".yaml"))
        os.rename(tmp, dest)
        parts.clear()
        return dest
    except (OSError, ValueError) as exc:   # ValueError: the request ended, its file closed
        return exc if isinstance(exc, OSError) else OSError(errno.EIO, str(exc))
    finally:
        for p in parts:
            if os.path.lexists(p):
                p.unlink()


def _free_name(folder, name):
    """``name`` or a variant of it whose input and sidecar are both free: an existing
    sidecar of the same stem would otherwise be taken for the upload's."""
    dest = unique_path(Path(folder) / name)
    while os.path.lexists(dest.with_name(dest.stem + ".yaml")):
        dest = unique_path(dest.with_name(dest.stem + "-web" + dest.suffix))
    return dest


def _has(sidecar):
    if sidecar is None:
        return False
    return bool(sidecar) if isinstance(sidecar, bytes) else bool(sidecar.filename)


def _write(path, sidecar):
    if isinstance(sidecar, bytes):
        path.write_bytes(sidecar)
    else:
        sidecar.save(str(path))
