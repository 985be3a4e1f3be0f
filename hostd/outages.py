"""The outages a printer host rides out: its SD card full, the network share gone, a second
hostd writing this node's lease, a damaged job database replaced.

An object that owns what each outage is while it lasts, handed the configuration, the job
store, the printers and the farm. Each is told once, prints going on, nothing new started
until it is over; the guards (:meth:`Outages.full_ok`, :meth:`Outages.share_ok`) note a
failed write instead of raising it, so one outage never stops the run loop.
"""

import contextlib
import logging
import os
import time
from pathlib import Path

from hostd import farm as farm_mod
from hostd import jobs as J
from hostd.errors import HostdError

log = logging.getLogger("hostd.daemon")
FULL_RETRY_S = 30.0     # while the job database cannot grow: how often to try again
# What can keep a node from taking work (the page shows the texts, /metrics the kinds).
PROBLEMS = ("disk_full", "share", "stuck", "node_id", "damaged")
TWIN_FIX = ("give each node its own node_id in hostd.yaml (by default it is the hostname, "
            "which a cloned SD card keeps), then restart both")


def twin_text(node_id, other):
    return ("another hostd uses node_id %r on this share: %s writes the same lease"
            % (node_id, farm_mod.holder_text(other)))


class Outages:
    """What keeps this node from writing or from taking work, while it lasts.

    full : the jobs.disk_full HostdError while the job database cannot grow, else None;
    full_at : when a write last failed for it (time.monotonic, s); share : the OSError while
    the share cannot be written; twin : what another hostd writing this node's lease says;
    damaged : what replaced a damaged job database, until the printers resume.
    """

    def __init__(self, config, store, slots, farm):
        self.config = config
        self.store = store
        self.slots = slots
        self.farm = farm
        self.full = None
        self.full_at = 0.0
        self._full_retry = 0.0
        self.share = None
        self.damaged = None
        self.twin = None
        self._twin_at = 0.0

    # -- the job database full ---------------------------------------------------------------

    def may_write(self, now):
        """Whether the loop may write to the store this round (``now``: time.monotonic)."""
        if self.full is None:
            return True
        if now < self._full_retry:
            return False
        self._full_retry = now + FULL_RETRY_S
        with self.full_ok():
            self.store.probe()
            return True
        return False

    @contextlib.contextmanager
    def full_ok(self):
        """Writes inside may find the job database full: noted (and told once), not raised."""
        try:
            yield
        except HostdError as exc:
            if exc.code != J.DISK_FULL:
                raise
            if self.full is None:
                log.error("%s. Prints already running go on; no file is taken and nothing "
                          "starts until there is room.", exc.text())
            self.full, self.full_at = exc, time.monotonic()

    def full_ended(self):
        self.full = None
        log.info("the job database takes writes again; carrying on")

    # -- the share -----------------------------------------------------------------------------

    @contextlib.contextmanager
    def share_ok(self):
        """Share operations inside may fail (gone, read-only): noted (told once), not raised."""
        try:
            yield
        except OSError as exc:
            if self.share is None:
                log.error("%s (%s). Prints already running go on; no file is taken and nothing "
                          "starts until it is back. Other nodes release this node's claimed "
                          "files after lease_s without a lease renewal. Fix: check the share's "
                          "mount and network.", self.share_text(exc), exc)
            self.share = exc

    def share_text(self, exc):
        # The folder, not the file: temporary names would change the text at every
        # heartbeat, and the page reloads when it changes.
        where = " or ".join(str(f) for f in self._share_folders(exc))
        return "cannot write to the share (%s): %s" % (where, exc.strerror or type(exc).__name__)

    def _share_folders(self, exc):
        """The folders a failed share operation wrote to (a move names two)."""
        names = [n for n in (exc.filename, getattr(exc, "filename2", None)) if n]
        return list(dict.fromkeys(Path(os.fsdecode(n)).parent for n in names)) or \
            [self.config.drop_dir]

    def share_takes_writes(self):
        """Whether every folder the outage's failure named takes a small file again.

        The lease renewing is not enough: it is one folder, and a folder such as done/ can
        refuse files (permissions, quota, a file in its place) while the lease renews, so
        the outage would end and begin again at every heartbeat. A folder no longer there
        is tried through the nearest one that is (a claim folder emptied meanwhile), since
        a share that is not mounted already fails the lease.
        """
        for folder in self._share_folders(self.share):
            while not folder.exists() and folder.parent != folder:
                folder = folder.parent
            probe = folder / (".hostd-probe-%s" % self.config.node_id)
            try:
                probe.write_bytes(b"hostd\n")
                probe.unlink()
            except OSError:
                return False
        return True

    def share_ended(self):
        self.share = None
        log.info("the share takes writes again; carrying on")

    # -- a second hostd with this node's id --------------------------------------------------------

    def twin_seen(self, other, now):
        """After a lease renewal: a second hostd with our node_id would take and adopt our
        files as its own, so while one shows, neither takes nor starts anything."""
        if other:
            if self.twin is None:
                log.error("%s. Nothing is taken or started until it is gone; prints already "
                          "running go on. Fix: %s.", twin_text(self.config.node_id, other),
                          TWIN_FIX)
            self.twin, self._twin_at = twin_text(self.config.node_id, other), now
        elif self.twin is not None and now - self._twin_at > self.config.lease_s:
            self.twin = None
            log.info("no other hostd has written node %s's lease for %.0f s; carrying on",
                     self.config.node_id, self.config.lease_s)

    # -- for people ------------------------------------------------------------------------------

    def problems(self, stuck=None):
        """What keeps this node from taking work, by kind (one of :data:`PROBLEMS`);
        ``stuck``: the watchdog's text while the run loop is stuck."""
        # Asked from the web's threads while the loop sets and clears these: read once.
        full, share = self.full, self.share
        found = {"disk_full": full.text() if full is not None else None,
                 "share": self.share_text(share) if share is not None else None,
                 "stuck": stuck,
                 "node_id": self.twin,
                 "damaged": self.damaged if any(s.paused for s in self.slots) else None}
        return {kind: text for kind, text in found.items() if text}
