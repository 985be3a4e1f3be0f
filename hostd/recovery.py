"""Putting the job store right: after a crash or restart, a full job database, a lost share.

The daemon's run loop stays the only writer; this room holds what it does when the store
and the world disagree (a file claimed but never recorded, a plan or a print that ended
while nothing could be written). An object handed the configuration, the job store, the
printers, the farm, the plans, the intake, the printers' room, the endings and the
outages (:mod:`hostd.outages`: what each outage is while it lasts).
"""

import logging
import os

from hostd import farm as farm_mod
from hostd import jobs as J
from hostd.watcher import INPUT_SUFFIXES

log = logging.getLogger("hostd.daemon")


class Recovery:
    """The store made to agree with what happened while it could not be written."""

    def __init__(self, config, store, slots, farm, plans, intake, printing, endings, outages):
        self.config = config
        self.store = store
        self.slots = slots
        self.farm = farm
        self.plans = plans
        self.intake = intake
        self.printing = printing
        self.endings = endings
        self.outages = outages

    def recover(self):
        """At start: jobs left planning are queued again, jobs left printing interrupted
        (their printer held), jobs whose files are gone cancelled, claimed files adopted."""
        for job_id in self.store.recover():
            job = self.store.get(job_id)
            if job["state"] == J.QUEUED:
                log.warning("job %s: %s was being planned when hostd stopped; planning it again",
                            job_id, job["rel_path"])
            if job["state"] == J.INTERRUPTED:
                self._interrupted(job)
        for job in self.store.list([J.QUEUED, J.READY]):
            if not os.path.exists(job["input_path"]):
                self.store.set_state(job["id"], J.CANCELLED, "input is gone from the claim "
                                     "folder (released to other nodes while this node was away)")
            elif job["state"] == J.READY and not self.printing.gcode(job):
                self.store.set_state(job["id"], J.QUEUED, "outputs missing: planning again")
        self.adopt_claimed()

    def _interrupted(self, job):
        for slot in self.slots:
            if slot.name == job["printer"] and slot.held is None:
                self.printing.hold(slot, "the print of %s was interrupted when hostd stopped"
                                   % job["name"])
        self.endings.to_failed(job, "The print of %s was interrupted: the daemon stopped or "
                                    "crashed while printing (last confirmed line %d). The "
                                    "printer is held: clear the bed, resume the printer, "
                                    "then print it again with `hostd requeue %s`."
                               % (job["name"], job["last_line"], job["id"]))
        # Said once it is true: a person (or a script) reading it looks in failed/ at once.
        log.warning("job %s: %s was printing when hostd stopped (last confirmed line %d); "
                    "interrupted, the file is in failed/", job["id"], job["rel_path"],
                    job["last_line"])

    def hold_after_damage(self, damaged, verdict):
        """A new job database replaced a damaged one: the claimed files are jobs again
        (:meth:`recover` adopted them), but which one was printing is not known, so no
        printer starts one before a person has looked at its bed."""
        for slot in self.slots:
            slot.paused = True
            self.store.set_printer(slot.name, paused=1)
        self.outages.damaged = (
            "the job database was damaged (SQLite: %s) and a new one started; the old one is "
            "kept as %s. Printers are held: check each bed, then resume the printer"
            % (verdict, damaged))
        log.error("%s (page, or `hostd resume NAME`). The files this node had claimed are "
                  "queued again; the jobs' history is in the old file (`sqlite3 %s .recover` "
                  "gets most of it back). A power cut on an SD card does this; if it comes "
                  "back, replace the card.", self.outages.damaged, damaged)

    def adopt_claimed(self):
        """Record files claimed but never recorded (a crash, a full job database)."""
        known = {j["input_path"] for j in self.store.list(J.ACTIVE)}
        for path in sorted(self.farm.claim_dir.glob("*/*")):
            if path.suffix.lower() in INPUT_SUFFIXES and str(path) not in known:
                target = None if path.parent.name == farm_mod.ROOT_TARGET else path.parent.name
                side = path.with_name(path.stem + ".yaml")
                self.intake.add_job(path.name, (target + "/" if target else "") + path.name,
                                    path, side if side.exists() else None, target)

    def resync(self):
        """After an outage: make the store agree with what happened meanwhile."""
        held = {s.job_id: s for s in self.slots if s.job_id is not None}
        for job in self.store.list([J.PLANNING, J.READY]):
            if job["state"] == J.PLANNING and job["id"] not in self.plans:
                self.store.set_state(job["id"], J.QUEUED, "planned while the job database "
                                     "was full: planning again")
            elif job["id"] in held:
                self.store.set_state(job["id"], J.PRINTING, "printing on %s" % held[job["id"]].name,
                                     printer=held[job["id"]].name)
        self.adopt_claimed()

    def full_back(self):
        """A round wrote without the job database refusing: an outage of it is over."""
        if self.outages.full is not None:
            self.resync()
            self.outages.full_ended()

    def share_back(self):
        """At a heartbeat: a share outage is over once every folder it named takes writes."""
        o = self.outages
        if o.share is not None and o.share_takes_writes():
            o.share_ended()
            with o.full_ok():
                self.resync()
