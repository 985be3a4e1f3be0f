"""The node's own copies of the plans it made: what its printers print.

The outbox and its plan cache are on the share, and whoever can write the share could
edit a plan's G-code there; a printer must never run that. Each plan this node makes
writes its G-code and report first into ``STATE/plans/.tmp-JOB/`` on the node's own disk
(the plan process is the node's, and nothing else writes there), and the share gets a
copy for people to read. A finished plan's folder becomes ``STATE/plans/KEY/``: a job
prints ``STATE/plans/KEY/plan.gcode``, and a plan found in the share's cache is used
only when this node holds its own copy under the same key (else it is planned again).
"""

import os
import shutil
from pathlib import Path

GCODE = "plan.gcode"
REPORT = "plan.report.json"     # ends in .report.json: hostd.reports reads it as a plan's
# Plans kept beyond those of the jobs not finished yet: each is the G-code of one part
# (1-10 MB), so a re-dropped file of the last few dozen prints without a new plan.
KEEP = 40


class Kept:
    """``STATE/plans``: one folder per plan key."""

    def __init__(self, state_dir):
        self.root = Path(state_dir) / "plans"

    def staging(self, job_id):
        """A fresh folder for the plan of ``job_id`` to write its G-code and report into."""
        d = self.root / (".tmp-" + job_id)
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        return d

    def discard(self, job_id):
        shutil.rmtree(self.root / (".tmp-" + job_id), ignore_errors=True)

    def keep(self, job_id, key):
        """Make the staged plan of ``job_id`` the node's copy of plan ``key``."""
        tmp, dest = self.root / (".tmp-" + job_id), self.root / key
        if not (tmp / GCODE).is_file():
            raise FileNotFoundError(tmp / GCODE)
        shutil.rmtree(dest, ignore_errors=True)
        os.replace(tmp, dest)

    def folder(self, key):
        """The node's copy of plan ``key`` (its G-code and report), or None."""
        d = self.root / key if key else None
        return d if d is not None and (d / GCODE).is_file() else None

    def gcode(self, key):
        d = self.folder(key)
        return d / GCODE if d is not None else None

    def prune(self, in_use):
        """Remove the oldest plans past :data:`KEEP`, never one of the keys ``in_use``."""
        try:
            found = [e for e in os.scandir(self.root)
                     if e.is_dir(follow_symlinks=False) and not e.name.startswith(".")]
        except OSError:
            return
        found.sort(key=lambda e: e.stat(follow_symlinks=False).st_mtime, reverse=True)
        for e in found[KEEP:]:
            if e.name not in in_use:
                shutil.rmtree(e.path, ignore_errors=True)
