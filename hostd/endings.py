"""How a job ends without printing to the end: its input filed in failed/ beside
``NAME.error.txt``, its state recorded with the reason.

An object handed the configuration and the job store; intake, planning, control and the
printers all end jobs through it, so the reason a person reads is worded one way.
"""

import logging
import os
from pathlib import Path, PurePosixPath

from hostd import jobs as J
from hostd.errors import bounded
from hostd.farm import archive_failed

log = logging.getLogger("hostd.daemon")


class Endings:
    """Failing, cancelling and interrupting jobs (config: :class:`hostd.config.Config`,
    store: :class:`hostd.jobs.JobStore`)."""

    def __init__(self, config, store):
        self.config = config
        self.store = store

    def fail(self, job, reason, code=None):
        self.failing(job, reason, code)()

    def failing(self, job, reason, code=None):
        """The move of a failed job's input; returns the call that records it."""
        # People know the files by the names they dropped, not by their claimed paths.
        reason = reason.replace(str(job["input_path"]), job["rel_path"])
        if job["sidecar_path"]:
            dropped = PurePosixPath(job["rel_path"])
            reason = reason.replace(str(job["sidecar_path"]),
                                    str(dropped.with_name(dropped.stem + ".yaml")))
        reason = bounded(reason)
        log.warning("job %s failed: %s", job["id"], reason)
        return self.filing(job, reason, state=J.FAILED, code=code or "job.failed")

    def to_failed(self, job, reason, state=None, code=None):
        """Move the input to failed/ beside NAME.error.txt and record ``state``."""
        self.filing(job, reason, state, code)()

    def filing(self, job, reason, state=None, code=None):
        """The move of :meth:`to_failed`; returns the call that records ``state``."""
        values = {}
        if os.path.exists(job["input_path"]) and Path(job["input_path"]).parent != \
                Path(self.config.failed_dir):
            text = ("%s\n\nFile: %s\nJob: %s (node %s)\nTo try again: change the file here, or "
                    "its sidecar (same name, .yaml; write one if there is none), then `hostd "
                    "requeue %s` or Requeue on the status page.\n" % (
                        reason, job["rel_path"], job["id"], self.config.node_id, job["id"]))
            dest, side = archive_failed(job["input_path"], job["sidecar_path"],
                                        self.config.failed_dir, job["name"], text)
            values = dict(input_path=str(dest), sidecar_path=str(side) if side else None)

        def record():
            if state is not None and state != job["state"]:
                self.store.set_state(job["id"], state, reason, error=reason, error_code=code,
                                     **values)
            elif values:
                self.store.update(job["id"], **values)
        return record
