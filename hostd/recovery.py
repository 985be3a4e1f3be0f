"""Putting the job store right: after a crash or restart, a full job database, a lost share.

The daemon's run loop stays the only writer; this mixin holds what it does when the
store and the world disagree (a file claimed but never recorded, a plan or a print
that ended while nothing could be written), and how it rides out the two outages a
printer host sees (its SD card full, the network share gone): told once, prints going
on, nothing new started until it is over.
"""

import contextlib
import logging
import os
import time
from pathlib import Path

from hostd import farm as farm_mod
from hostd import jobs as J
from hostd.errors import HostdError
from hostd.watcher import INPUT_SUFFIXES

log = logging.getLogger("hostd.daemon")
FULL_RETRY_S = 30.0     # while the job database cannot grow: how often to try again
# What can keep a node from taking work (the page shows the texts, /metrics the kinds).
PROBLEMS = ("disk_full", "share", "stuck", "node_id", "damaged")
TWIN_FIX = ("give each node its own node_id in hostd.yaml (by default it is the hostname, "
            "which a cloned SD card keeps), then restart both")


class RecoveryMixin:
    """Recovery of :class:`hostd.daemon.Daemon` (uses its store, slots, plans and farm)."""

    _full = None        # the jobs.disk_full error while the job database cannot grow
    _full_at = 0.0      # when a write last failed for it
    _full_retry = 0.0
    _share = None       # the OSError while the share cannot be written
    _damaged = None     # what replaced a damaged job database, until the printers resume
    _twin = None        # another hostd writing this node's lease: what it says
    _twin_at = 0.0

    def _recover(self):
        for job_id in self.store.recover():
            job = self.store.get(job_id)
            if job["state"] == J.QUEUED:
                log.warning("job %s: %s was being planned when hostd stopped; planning it again",
                            job_id, job["rel_path"])
            if job["state"] == J.INTERRUPTED:
                for slot in self.slots:
                    if slot.name == job["printer"] and slot.held is None:
                        self._hold(slot, "the print of %s was interrupted when hostd stopped"
                                   % job["name"])
                log.warning("job %s: %s was printing when hostd stopped (last confirmed line %d); "
                            "interrupted, the file is in failed/", job_id, job["rel_path"],
                            job["last_line"])
                self._to_failed(job, "The print of %s was interrupted: the daemon stopped or "
                                     "crashed while printing (last confirmed line %d). The "
                                     "printer is held: clear the bed, resume the printer, "
                                     "then print it again with "
                                     "`hostd requeue %s`." % (job["name"], job["last_line"],
                                                             job_id))
        for job in self.store.list([J.QUEUED, J.READY]):
            if not os.path.exists(job["input_path"]):
                self.store.set_state(job["id"], J.CANCELLED, "input is gone from the claim "
                                     "folder (released to other nodes while this node was away)")
            elif job["state"] == J.READY and not self._gcode(job):
                self.store.set_state(job["id"], J.QUEUED, "outputs missing: planning again")
        self._adopt_claimed()

    def _hold_after_damage(self, damaged, verdict):
        """A new job database replaced a damaged one: the claimed files are jobs again
        (``_recover`` adopted them), but which one was printing is not known, so no
        printer starts one before a person has looked at its bed."""
        for slot in self.slots:
            slot.paused = True
            self.store.set_printer(slot.name, paused=1)
        self._damaged = ("the job database was damaged (SQLite: %s) and a new one started; "
                         "the old one is kept as %s. Printers are held: check each bed, then "
                         "resume the printer" % (verdict, damaged))
        log.error("%s (page, or `hostd resume NAME`). The files this node had claimed are "
                  "queued again; the jobs' history is in the old file (`sqlite3 %s .recover` "
                  "gets most of it back). A power cut on an SD card does this; if it comes "
                  "back, replace the card.", self._damaged, damaged)

    def _adopt_claimed(self):
        """Record files claimed but never recorded (a crash, a full job database)."""
        known = {j["input_path"] for j in self.store.list(J.ACTIVE)}
        for path in sorted(self.farm.claim_dir.glob("*/*")):
            if path.suffix.lower() in INPUT_SUFFIXES and str(path) not in known:
                target = None if path.parent.name == farm_mod.ROOT_TARGET else path.parent.name
                side = path.with_name(path.stem + ".yaml")
                self._add_job(path.name, (target + "/" if target else "") + path.name, path,
                              side if side.exists() else None, target)

    def _resync(self):
        """After an outage: make the store agree with what happened meanwhile."""
        held = {s.job_id: s for s in self.slots if s.job_id is not None}
        for job in self.store.list([J.PLANNING, J.READY]):
            if job["state"] == J.PLANNING and job["id"] not in self.plans:
                self.store.set_state(job["id"], J.QUEUED, "planned while the job database "
                                     "was full: planning again")
            elif job["id"] in held:
                self.store.set_state(job["id"], J.PRINTING, "printing on %s" % held[job["id"]].name,
                                     printer=held[job["id"]].name)
        self._adopt_claimed()

    def _may_write(self, now):
        if self._full is None:
            return True
        if now < self._full_retry:
            return False
        self._full_retry = now + FULL_RETRY_S
        with self._full_ok():
            self.store.probe()
            return True
        return False

    @contextlib.contextmanager
    def _full_ok(self):
        """Writes inside may find the job database full: noted (and told once), not raised."""
        try:
            yield
        except HostdError as exc:
            if exc.code != J.DISK_FULL:
                raise
            if self._full is None:
                log.error("%s. Prints already running go on; no file is taken and nothing "
                          "starts until there is room.", exc.text())
            self._full, self._full_at = exc, time.monotonic()

    @contextlib.contextmanager
    def _share_ok(self):
        """Share operations inside may fail (gone, read-only): noted (told once), not raised."""
        try:
            yield
        except OSError as exc:
            if self._share is None:
                log.error("%s (%s). Prints already running go on; no file is taken and nothing "
                          "starts until it is back. Other nodes release this node's claimed "
                          "files after lease_s without a lease renewal. Fix: check the share's "
                          "mount and network.", self._share_text(exc), exc)
            self._share = exc

    def _share_text(self, exc):
        # The folder, not the file: temporary names would change the text at every
        # heartbeat, and the page reloads when it changes.
        where = " or ".join(str(f) for f in self._share_folders(exc))
        return "cannot write to the share (%s): %s" % (where, exc.strerror or type(exc).__name__)

    def _share_folders(self, exc):
        """The folders a failed share operation wrote to (a move names two)."""
        names = [n for n in (exc.filename, getattr(exc, "filename2", None)) if n]
        return list(dict.fromkeys(Path(os.fsdecode(n)).parent for n in names)) or \
            [self.config.drop_dir]

    def _share_takes_writes(self):
        """Whether every folder the outage's failure named takes a small file again.

        The lease renewing is not enough: it is one folder, and a folder such as done/ can
        refuse files (permissions, quota, a file in its place) while the lease renews, so
        the outage would end and begin again at every heartbeat. A folder no longer there
        is tried through the nearest one that is (a claim folder emptied meanwhile), since
        a share that is not mounted already fails the lease.
        """
        for folder in self._share_folders(self._share):
            while not folder.exists() and folder.parent != folder:
                folder = folder.parent
            probe = folder / (".hostd-probe-%s" % self.config.node_id)
            try:
                probe.write_bytes(b"hostd\n")
                probe.unlink()
            except OSError:
                return False
        return True

    def _twin_text(self, other):
        return ("another hostd uses node_id %r on this share: %s writes the same lease"
                % (self.config.node_id, farm_mod.holder_text(other)))

    def _twin_seen(self, other, now):
        """After a lease renewal: a second hostd with our node_id would take and adopt our
        files as its own, so while one shows, neither takes nor starts anything."""
        if other:
            if self._twin is None:
                log.error("%s. Nothing is taken or started until it is gone; prints already "
                          "running go on. Fix: %s.", self._twin_text(other), TWIN_FIX)
            self._twin, self._twin_at = self._twin_text(other), now
        elif self._twin is not None and now - self._twin_at > self.config.lease_s:
            self._twin = None
            log.info("no other hostd has written node %s's lease for %.0f s; carrying on",
                     self.config.node_id, self.config.lease_s)

    def _full_back(self):
        if self._full is not None:
            self._resync()
            self._full = None
            log.info("the job database takes writes again; carrying on")

    def _share_back(self):
        if self._share is not None and self._share_takes_writes():
            self._share = None
            log.info("the share takes writes again; carrying on")
            with self._full_ok():
                self._resync()

    def problems(self):
        """What keeps this node from taking work, by kind (one of :data:`PROBLEMS`)."""
        # Asked from the web's threads while the loop sets and clears these: read once.
        full, share, watch = self._full, self._share, self.watch
        found = {"disk_full": full.text() if full is not None else None,
                 "share": self._share_text(share) if share is not None else None,
                 "stuck": watch.problem if watch is not None else None,
                 "node_id": self._twin,
                 "damaged": self._damaged if any(s.paused for s in self.slots) else None}
        return {kind: text for kind, text in found.items() if text}

    @property
    def problem(self):
        """The same for people, in one line (None: nothing)."""
        return "; ".join(self.problems().values()) or None
