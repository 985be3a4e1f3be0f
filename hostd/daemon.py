"""The run loop of ``hostd run``: drop folder -> claim -> plan -> print -> archive.

One thread owns the loop (and the job store); each printer link has its own driver
thread, each plan its own process. Every tick: answer control requests from the
terminal commands, take complete files from the drop folder, start and reap plans,
follow prints and hand ready jobs to idle printers, and every ``heartbeat_s`` renew
the claim lease and publish the node status. systemd's watchdog is fed from a thread of
its own (:mod:`hostd.watchdog`), so a loop stuck on a share that does not answer ends no
print.

The daemon wires its rooms, each an object that owns its state and is handed what it
uses, and looks them up by name: intake (:mod:`hostd.intake`), plans
(:mod:`hostd.plans`), printing (:mod:`hostd.printing`), control (:mod:`hostd.control`),
recovery (:mod:`hostd.recovery`), outages (:mod:`hostd.outages`), endings
(:mod:`hostd.endings`), routes (:mod:`hostd.routes`).

On SIGTERM/SIGINT the loop stops feeding printers (cancel script: heaters off, lift,
motors off), leaves printing jobs ``interrupted``, stops the plans (their jobs are
planned again on the next start) and exits within ``stop_timeout_s``.
"""

import logging
import os
import shutil
import signal
import threading
import time
from pathlib import Path

from hostd import jobs as J
from hostd import runtime
from hostd.control import Control
from hostd.endings import Endings
from hostd.errors import HostdError
from hostd.farm import Farm
from hostd.intake import Intake
from hostd.lock import DaemonLock
from hostd.notify import Notifier
from hostd.outages import PROBLEMS, TWIN_FIX, Outages, twin_text
from hostd.plans import Plans
from hostd.printing import Printing
from hostd.recovery import Recovery
from hostd.routes import Routes
from hostd.slot import Slot
from hostd.watchdog import LoopWatch
from hostd.watcher import Watcher

log = logging.getLogger("hostd.daemon")
TICK_S = 0.05
_NONE = object()


class Daemon:
    """The node: its parts wired together and looked up by name (:meth:`lookup`, or as
    attributes: ``daemon.store``, ``daemon.control``).

    Parts: routes, farm, watcher (from the start); store, endings, outages, plans,
    printing, intake, control, recovery (once the job store is open, in :meth:`setup`).
    """

    def __init__(self, config, notifier=None):
        self.config = config
        self.notify = notifier or Notifier()
        self.stop_event = threading.Event()
        self.slots = [Slot(p) for p in config.printers]
        self.lock = DaemonLock(config.lock_path)
        self.web = None
        self.watch = None
        self._parts = {}
        self._next_beat = 0.0
        self.add("routes", Routes(config.node_id, self.slots))
        self.add("farm", Farm(config.drop_dir, config.node_id, config.lease_s))
        self.add("watcher", Watcher(config.drop_dir, config.settle_s, config.poll_s))

    # -- parts -------------------------------------------------------------------------------

    def add(self, name, part):
        self._parts[name] = part
        return part

    def lookup(self, name, default=_NONE):
        """The part called ``name``; without ``default``, a missing one is a HostdError."""
        part = self._parts.get(name, default)
        if part is _NONE:
            raise HostdError("no part %r in this daemon" % name, code="daemon.no_part",
                             fix="parts: " + ", ".join(self._parts))
        return part

    def __getattr__(self, name):
        parts = self.__dict__.get("_parts", {})
        if name in parts:
            return parts[name]
        raise AttributeError("%s has no attribute or part %r" % (type(self).__name__, name))

    def _wire(self, store):
        """The rooms that use the job store, each handed what it uses."""
        c, slots, routes, farm = self.config, self.slots, self.routes, self.farm
        self.add("store", store)
        endings = self.add("endings", Endings(c, store))
        outages = self.add("outages", Outages(c, store, slots, farm))
        plans = self.add("plans", Plans(c, store, routes.why_not, endings.fail, outages.full_ok))
        printing = self.add("printing", Printing(c, store, slots, routes, endings,
                                                 outages, plans))
        intake = self.add("intake", Intake(c, store, self.watcher, farm, routes, slots, endings))
        self.add("control", Control(c, store, slots, plans, farm, routes, endings, printing))
        self.add("recovery", Recovery(c, store, slots, farm, plans, intake, printing, endings,
                                      outages))

    # -- lifecycle --------------------------------------------------------------------------

    def setup(self):
        c = self.config
        self.lock.acquire()
        for d in (c.drop_dir, c.state_dir, c.outbox_dir, c.done_dir, c.failed_dir):
            Path(d).mkdir(parents=True, exist_ok=True)
        twin = self.farm.held_by_another(2 * c.heartbeat_s + 1.0)
        if twin:
            self.lock.release()
            raise HostdError(twin_text(c.node_id, twin), code="config.node_id", file=c.source,
                             key="node_id", fix=TWIN_FIX)
        store, damaged, verdict = J.open_checked(c.db_path)
        self._wire(store)
        # Nothing prints before the loop starts: copies left by a crash can go.
        shutil.rmtree(c.spool_dir, ignore_errors=True)
        self.farm.setup()
        self.recovery.recover()
        self.printing.connect()
        if damaged is not None:
            self.recovery.hold_after_damage(damaged, verdict)
        self.watcher.start()
        if c.web.port is not None:
            from hostd.web import server as web_server
            self.web = web_server.start(c, self.store, self)
        log.info("node %s watching %s with %d printer(s)", c.node_id, c.drop_dir, len(self.slots))
        self.notify.ready("watching %s" % c.drop_dir)
        self.watch = LoopWatch(self.notify, self.printing.busy,
                               min(c.heartbeat_s, self.notify.watchdog_s or c.heartbeat_s))
        self.watch.start()

    def request_stop(self, *_):
        self.stop_event.set()

    def run(self):
        """Set up, loop until asked to stop, shut down; returns the exit status."""
        self.setup()
        runtime.publish(self.config, Path.cwd())   # terminal commands find it from anywhere
        try:
            while not self.stop_event.is_set():
                try:
                    self.tick()
                except Exception:
                    # One bad job or a flaky share must not take every printer down with it.
                    log.exception("error in the run loop; carrying on")
                    self.stop_event.wait(1.0)
                self.stop_event.wait(TICK_S)
        finally:
            runtime.withdraw()
            self.shutdown()
        return 0

    def tick(self):
        now = time.monotonic()
        out = self.outages
        # A full job database or a lost share stops everything that starts work (a claimed
        # file must be recorded, a started plan or print too), never the prints running.
        writable = out.may_write(now)
        starting = writable and out.share is None and out.twin is None
        with out.full_ok(), out.share_ok():
            if writable:
                self.control.answer()
            if starting:
                self.intake.take_new(now)
                self.plans.reap()
                self.plans.start()
            self.printing.follow()
            if starting:
                self.printing.dispatch()
            if writable and out.full_at < now:   # no write failed in this tick
                self.recovery.full_back()
        if now >= self._next_beat:
            self._next_beat = now + self.config.heartbeat_s
            self._heartbeat()
        self.watch.tick()     # a whole round: neither stuck nor failing every time

    def shutdown(self):
        self.notify.stopping("stopping")
        log.info("stopping")
        deadline = time.monotonic() + max(1.0, self.config.stop_timeout_s - 3.0)
        out = self.outages
        # With the job database full, the next start records what is left unrecorded here.
        for job_id in self.plans.stop_all():
            with out.full_ok():
                self.store.set_state(job_id, J.QUEUED, "daemon stopped while planning: will "
                                                       "plan again on the next start")
        self.printing.stop(deadline)
        self.watcher.stop()
        if self.web is not None:
            self.web.stop()
        for slot in self.slots:
            slot.close()
            with out.full_ok():
                self.store.set_printer(slot.name, state="stopped", job_id=None)
        self._heartbeat(state="stopped")
        if self.watch is not None:
            self.watch.stop()
        self.store.close()
        self.lock.release()

    # -- status ------------------------------------------------------------------------------

    def status(self, state="running"):
        printers = []
        for slot in self.slots:
            snap = slot.link_job.snapshot() if slot.link_job is not None else None
            job = self.store.get(slot.job_id) if slot.job_id is not None else None
            printers.append({"name": slot.name, "profile": slot.config.profile,
                             "state": slot.state, "paused": slot.paused, "job": slot.job_id,
                             "job_name": job["name"] if job else None,
                             "error": slot.error, "progress": round(snap["confirmed"] / snap[
                                 "total"], 4) if snap and snap["total"] else None})
        queued = len(self.store.list([J.QUEUED, J.PLANNING, J.READY]))
        return {"state": state, "pid": os.getpid(), "printers": printers, "queue_length": queued,
                "planning": sorted(self.plans), "web_url": self.web.url if self.web else None,
                "problem": self.problem}

    def dropped(self):
        """Inputs in the drop folder at the last scan (asked from the web's threads)."""
        return self.intake.dropped()

    def problems(self):
        """What keeps this node from taking work, by kind (one of :data:`PROBLEMS`)."""
        watch = self.watch
        found = self.outages.problems(stuck=watch.problem if watch is not None else None)
        return {kind: found[kind] for kind in PROBLEMS if kind in found}

    @property
    def problem(self):
        """The same for people, in one line (None: nothing)."""
        return "; ".join(self.problems().values()) or None

    def _heartbeat(self, state="running"):
        out = self.outages
        with out.share_ok():
            out.twin_seen(self.farm.renew_lease(state), time.monotonic())
            self.recovery.share_back()
            if state == "running":
                self.farm.release_dead()
        status = self.status(state)
        if out.share is None:
            with out.share_ok():
                self.farm.publish_status(status)
        with out.full_ok():
            for slot in self.slots:
                self.store.set_printer(slot.name, state=slot.state)
        busy = [s for s in status["printers"] if s["job"]]
        self.notify.status("%d printing, %d queued, %d planning%s%s" % (
            len(busy), status["queue_length"], len(status["planning"]),
            "; job database full" if out.full is not None else "",
            "; share unreachable" if out.share is not None else ""))


def run(config):
    """Run the daemon in this process until SIGTERM/SIGINT; returns the exit status."""
    daemon = Daemon(config)
    old = {s: signal.signal(s, daemon.request_stop) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        return daemon.run()
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
