"""Intake: complete files in the drop folder become this node's jobs.

An object handed the configuration, the job store, the watcher, the farm, the routing rules,
the printers and the endings (how a job that cannot be taken fails). A file is claimed
(renamed into this node's claim folder) and recorded with its sidecar's options
and the profile it will be planned with; a node sharing the drop folder with other live
nodes takes only what it can start soon.

One file's fault never strands the others of a scan: it is logged, and a claimed file that
cannot be recorded goes to failed/ with the reason. An outage (the job database full, the
share failing) is no fault of a file: it stops the scan, and the loop's guards take it.
"""

import logging
import time

from hostd import jobs as J
from hostd.errors import HostdError, bounded
from hostd.farm import archive_failed
from hostd.names import one_owner
from hostd.watcher import name_problem, shown

log = logging.getLogger("hostd.daemon")
# Files are taken for at most this long per round of the loop, the rest at the next: a
# few thousand dropped at once took 40 s in one round, and the loop counts as stuck at 30.
SLICE_S = 0.5


def outage(exc):
    """Whether ``exc`` stops the whole node rather than one file: the job database full,
    or a file operation on the share failing."""
    return isinstance(exc, OSError) or (isinstance(exc, HostdError) and exc.code == J.DISK_FULL)


class Intake:
    """From the drop folder to a recorded job."""

    def __init__(self, config, store, watcher, farm, routes, slots, endings):
        self.config = config
        self.store = store
        self.watcher = watcher
        self.farm = farm
        self.routes = routes
        self.slots = slots
        self.endings = endings
        self._skipped = set()      # drop paths told once as meant for no printer here

    def take_new(self, now):
        room = None
        cands = self.watcher.poll(now)
        end = time.monotonic() + SLICE_S
        for i, cand in enumerate(cands):
            if i and time.monotonic() >= end:
                for rest in cands[i:]:
                    self.watcher.forget(rest)
                self.watcher.wake.set()     # scan again at the next round, not after poll_s
                return
            room = self.claim_room() if room is None else room
            if room <= 0:
                self.watcher.forget(cand)   # offered again at the next scan
                continue
            try:
                if self.take(cand):
                    room -= 1
            except Exception as exc:
                if outage(exc):
                    for rest in cands[i:]:
                        self.watcher.forget(rest)   # offered again once it is over
                    raise
                log.exception("%s: could not be taken", shown(cand.rel_path))

    def dropped(self):
        """Inputs in the drop folder at the last scan (asked from the web's threads):
        [{"file": rel path, "bytes", "complete", "this_node": whether its folder targets
        this node}]."""
        return [{"file": rel, "bytes": size, "complete": complete,
                 "this_node": self.routes.target_ok(rel.split("/")[0] if "/" in rel else None)}
                for rel, size, complete in self.watcher.inputs]

    def claim_room(self):
        """How many more files this node takes now. Alone it takes them all (they show up
        as jobs at once); with other live nodes on the share it holds ``claim_ahead`` per
        printer, queued to printing, and leaves the rest in the drop folder for them."""
        if not self.farm.live_peers():
            return float("inf")
        held = len(self.store.list(J.ACTIVE))
        return self.config.claim_ahead * len(self.slots) - held

    def take(self, cand):
        """Claim and record one complete file; True if this node took it."""
        if not self.routes.target_ok(cand.target):
            if cand.rel_path not in self._skipped:
                self._skipped.add(cand.rel_path)
                log.info("%s: folder %s is not a printer or profile of this node; leaving it",
                         shown(cand.rel_path), shown(cand.target))
            return False
        claimed = self.farm.claim(cand)
        if claimed is None:
            return False
        path, side = claimed
        self.add_job(cand.path.name, cand.rel_path, path, side, cand.target, cand.others)
        return True

    def add_job(self, name, rel_path, path, side, target, others=()):
        """Record a claimed file as a job; one that cannot be goes to failed/."""
        try:
            self._new_job(name, rel_path, path, side, target, others)
        except Exception as exc:
            if outage(exc):
                raise     # the file stays claimed, and is recorded once it is over
            self._not_recorded(name if not name_problem(name) else path.name, path, side,
                               shown(rel_path), exc)

    def _not_recorded(self, name, path, side, rel_path, exc):
        """File a claimed file whose recording failed on something unforeseen in failed/,
        with the reason: left in the claim folder it would be nobody's until a restart."""
        said = bounded(exc, 1000)
        log.error("%s: could not be recorded as a job (%s: %s); it goes to failed/",
                  rel_path, type(exc).__name__, said, exc_info=exc)
        text = ("hostd could not take %s: %s: %s. Nothing in the file is known to be wrong: "
                "this is a fault in hostd, and the log of node %s has the details" % (
                    rel_path, type(exc).__name__, said, self.config.node_id))
        job = next((j for j in self.store.list(J.ACTIVE) if j["input_path"] == str(path)), None)
        if job is not None:
            return self.endings.fail(job, text + ". If a requeue fails the same way, report it "
                                     "with that log", "job.intake_failed")
        archive_failed(path, side, self.config.failed_dir, name, text + ".\n\nTo try again, "
                       "move the file (and its sidecar) back into the drop folder; if it fails "
                       "the same way, report it with that log.")

    def _new_job(self, name, rel_path, path, side, target, others=()):
        from pipeline.errors import PipelineError
        from pipeline.input.heightfield import check_file
        from pipeline.input.sidecar import load_sidecar
        values = dict(target=target, node_id=self.config.node_id,
                      sidecar_path=str(side) if side else None)
        problem = name_problem(name)
        if problem:
            log.warning("%s: %s; taken as %s", shown(rel_path), problem, path.name)
            name, rel_path = path.name, shown(rel_path)
        try:
            # A broken file is refused as it is taken: junk must not queue for a plan.
            check_file(path)
            one_owner(rel_path, others)
            sidecar = load_sidecar(side) if side else None
        except PipelineError as exc:
            job_id = self.store.add(name, rel_path, path, **values)
            return self.endings.fail(self.store.get(job_id), exc.text(), exc.code)
        profile = self.routes.profile_for(target, sidecar)
        values.update(profile=profile, priority=sidecar.priority if sidecar else 0,
                      copies=sidecar.copies if sidecar else 1)
        job_id = self.store.add(name, rel_path, path, **values)
        log.info("job %s: %s claimed (profile %s)", job_id, rel_path, profile)
        job = self.store.get(job_id)
        why_not = self.routes.why_not(job)
        if why_not:
            return self.endings.fail(job, why_not, "job.no_printer")
