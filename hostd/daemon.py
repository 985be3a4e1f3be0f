"""The run loop of ``hostd run``: drop folder -> claim -> plan -> print -> archive.

One thread owns the loop (and the job store); each printer link has its own driver
thread, each plan its own process. Every tick: answer control requests from the
terminal commands, take complete files from the drop folder, start and reap plans,
follow prints and hand ready jobs to idle printers, and every ``heartbeat_s`` renew
the claim lease and publish the node status. systemd's watchdog is fed from a thread of
its own (:mod:`hostd.watchdog`), so a loop stuck on a share that does not answer ends no
print.

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
from pathlib import Path, PurePosixPath

from hostd import jobs as J
from hostd import runtime
from hostd.feed import job_feed
from hostd.control import ControlMixin
from hostd.intake import IntakeMixin
from hostd.farm import Farm, archive_done, archive_failed
from hostd.lock import DaemonLock
from hostd.notify import Notifier
from hostd.plans import Plans
from hostd.errors import HostdError, bounded
from hostd.recovery import TWIN_FIX, RecoveryMixin
from hostd.routes import Routes
from hostd.slot import Slot
from hostd.watchdog import LoopWatch
from hostd.watcher import Watcher

log = logging.getLogger("hostd.daemon")
TICK_S = 0.05
# A print's progress goes to the store this often, not every tick: each write appends pages
# to the WAL, and 20 a second were 80-90 kB/s of writes on a host's SD card.
PROGRESS_S = 2.0


class Daemon(ControlMixin, IntakeMixin, RecoveryMixin):
    def __init__(self, config, notifier=None):
        self.config = config
        self.notify = notifier or Notifier()
        self.stop_event = threading.Event()
        self.slots = [Slot(p) for p in config.printers]
        self.routes = Routes(config.node_id, self.slots)
        self.farm = Farm(config.drop_dir, config.node_id, config.lease_s)
        self.watcher = Watcher(config.drop_dir, config.settle_s, config.poll_s)
        self.plans = None            # hostd.plans.Plans, once the store is open
        self.lock = DaemonLock(config.lock_path)
        self.store = None
        self.web = None
        self.watch = None
        self._next_beat = 0.0
        self._next_reconnect = 0.0
        self._skipped = set()

    # -- lifecycle --------------------------------------------------------------------------

    def setup(self):
        c = self.config
        self.lock.acquire()
        for d in (c.drop_dir, c.state_dir, c.outbox_dir, c.done_dir, c.failed_dir):
            Path(d).mkdir(parents=True, exist_ok=True)
        twin = self.farm.held_by_another(2 * c.heartbeat_s + 1.0)
        if twin:
            self.lock.release()
            raise HostdError(self._twin_text(twin), code="config.node_id", file=c.source,
                             key="node_id", fix=TWIN_FIX)
        self.store, damaged, verdict = J.open_checked(c.db_path)
        self.plans = Plans(c, self.store, self.routes.why_not, self._fail, self._full_ok)
        # Nothing prints before the loop starts: copies left by a crash can go.
        shutil.rmtree(c.spool_dir, ignore_errors=True)
        self.farm.setup()
        self._recover()
        rows = self.store.printers()
        for slot in self.slots:
            # A hold outlives a restart: the failed print is still on that bed.
            slot.held = rows.get(slot.name, {}).get("held")
            slot.paused = slot.held is not None
            self.store.set_printer(slot.name, state="connecting", paused=int(slot.paused),
                                   job_id=None)
            slot.connect_async()
        if damaged is not None:
            self._hold_after_damage(damaged, verdict)
        self.watcher.start()
        if c.web.port is not None:
            from hostd.web import server as web_server
            self.web = web_server.start(c, self.store, self)
        log.info("node %s watching %s with %d printer(s)", c.node_id, c.drop_dir, len(self.slots))
        self.notify.ready("watching %s" % c.drop_dir)
        self.watch = LoopWatch(self.notify, self._holding_prints,
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
        # A full job database or a lost share stops everything that starts work (a claimed
        # file must be recorded, a started plan or print too), never the prints running.
        writable = self._may_write(now)
        starting = writable and self._share is None and self._twin is None
        with self._full_ok(), self._share_ok():
            if writable:
                self._control()
            if starting:
                self._take_new(now)
                self.plans.reap()
                self.plans.start()
            self._follow_prints()
            if starting:
                self._dispatch()
            if writable and self._full_at < now:   # no write failed in this tick
                self._full_back()
        if now >= self._next_beat:
            self._next_beat = now + self.config.heartbeat_s
            self._heartbeat()
        self.watch.tick()     # a whole round: neither stuck nor failing every time

    def shutdown(self):
        self.notify.stopping("stopping")
        log.info("stopping")
        deadline = time.monotonic() + max(1.0, self.config.stop_timeout_s - 3.0)
        # With the job database full, the next start records what is left unrecorded here.
        for job_id in self.plans.stop_all():
            with self._full_ok():
                self.store.set_state(job_id, J.QUEUED, "daemon stopped while planning: will "
                                                       "plan again on the next start")
        for slot in self.slots:
            if slot.job_id is not None and slot.link_job is not None:
                try:
                    slot.printer.cancel()   # stop feeding; heaters off, lift, motors off
                except Exception as exc:
                    log.warning("printer %s: cancel failed: %s", slot.name, exc)
        for slot in self.slots:
            if slot.job_id is not None:
                if slot.link_job is not None:
                    slot.link_job.wait(max(0.1, deadline - time.monotonic()))
                if self._full is None:
                    with self._full_ok():
                        self._interrupt(slot, "the daemon was stopped during the print")
        self.watcher.stop()
        if self.web is not None:
            self.web.stop()
        for slot in self.slots:
            slot.close()
            with self._full_ok():
                self.store.set_printer(slot.name, state="stopped", job_id=None)
        self._heartbeat(state="stopped")
        if self.watch is not None:
            self.watch.stop()
        self.store.close()
        self.lock.release()

    # -- planning --------------------------------------------------------------------------------

    def _gcode(self, job):
        return self.plans.gcode(job)     # the node's own copy (hostd.kept), never the share's

    # -- printing ---------------------------------------------------------------------------------

    def _dispatch(self):
        now = time.monotonic()
        if now >= self._next_reconnect:
            self._next_reconnect = now + 5.0
            for slot in self.slots:
                if slot.state in ("disconnected",) and slot.job_id is None:
                    slot.connect_async()
        held = {s.job_id for s in self.slots}
        for job in self.store.next_in_order(J.READY):
            if job["id"] in held or job["decision"]:   # started unrecorded, or a person decides
                continue
            for slot in self.slots:
                if slot.available() and self.routes.eligible(slot, job):
                    self._start_print(slot, job)
                    break

    def _start_print(self, slot, job):
        from hostd.printer import PrinterError
        gcode = self._gcode(job)
        if gcode is None:
            self.store.set_state(job["id"], J.QUEUED, "this node's copy of the G-code is "
                                 "missing: planning again")
            return
        rate = job_feed(gcode, slot.config.baud)
        try:
            slot.link_job = slot.printer.start(str(self._spool(job, gcode)), job_id=job["id"],
                                               prelude=rate.commands)
        except PrinterError as exc:
            log.warning("printer %s cannot start %s: %s", slot.name, job["id"], exc)
            self._unspool(job["id"])
            return
        slot.job_id = job["id"]
        self.store.set_state(job["id"], J.PRINTING, "printing on %s (copy %d of %d)%s" % (
            slot.name, job["copies_done"] + 1, job["copies"],
            "; " + rate.note if rate.note else ""), printer=slot.name,
            started_at=job["started_at"] or time.time(), progress=0.0)
        self.store.set_printer(slot.name, job_id=job["id"])
        log.info("job %s: printing %s on %s (copy %d of %d)", job["id"], job["name"], slot.name,
                 job["copies_done"] + 1, job["copies"])

    def _spool(self, job, gcode):
        """A copy of the G-code on the local disk to print from: the outbox is often on the
        share, and a share that goes away mid-print must not starve the printer."""
        dest = self.config.spool_dir / (job["id"] + ".gcode")
        part = dest.with_suffix(".part")
        try:
            dest.parent.mkdir(exist_ok=True)
            shutil.copyfile(gcode, part)
            os.replace(part, dest)
            return dest
        except OSError as exc:
            part.unlink(missing_ok=True)
            log.warning("job %s: cannot copy its G-code to %s (%s); printing it from the outbox",
                        job["id"], dest.parent, exc)
            return gcode

    def _unspool(self, job_id):
        (self.config.spool_dir / (job_id + ".gcode")).unlink(missing_ok=True)

    def _follow_prints(self):
        for slot in self.slots:
            if slot.job_id is None:
                continue
            snap = slot.link_job.snapshot()
            if snap["result"] is None:
                now = time.monotonic()
                if now < slot.progress_due:
                    continue
                slot.progress_due = now + PROGRESS_S
                total = snap["total"] or 0
                progress = snap["confirmed"] / total if total else 0.0
                with self._full_ok():   # the page shows live progress from the printer
                    self.store.update(slot.job_id, progress=round(progress, 4),
                                      last_line=snap["last_confirmed_line"])
                continue
            if slot.ending is None:
                if self._share is not None:
                    continue   # the input is filed once the share is back
                slot.ending = self._ending(slot, snap)
            slot.ending()   # may find the store full: the slot keeps the job until it is recorded
            self._unspool(slot.job_id)
            slot.job_id = slot.link_job = slot.ending = None
            self.store.set_printer(slot.name, job_id=None)

    def _ending(self, slot, snap):
        """File the input of a finished print; returns the call that records the outcome."""
        job = self.store.get(slot.job_id)
        if snap["result"] == "done":
            copies = job["copies_done"] + 1
            if copies < job["copies"]:
                return lambda: self.store.set_state(job["id"], J.READY, "copy %d printed" % copies,
                                                    copies_done=copies, progress=1.0)
            message = "printed on %s in %.0f s" % (slot.name, snap["seconds"])
            values = dict(copies_done=copies, progress=1.0, last_line=snap["last_confirmed_line"])
            if os.path.exists(job["input_path"]):
                dest, side = archive_done(job["input_path"], job["sidecar_path"],
                                          self.config.done_dir, job["name"])
                values.update(input_path=str(dest), sidecar_path=str(side) if side else None)
            else:
                message += ("; its file had left the claim folder (released to other nodes "
                            "while this node could not renew its lease), so it is not in done/")

            def record():
                self.store.set_state(job["id"], J.DONE, message, **values)
                log.info("job %s: %s %s", job["id"], job["name"], message)
            return record
        if snap["result"] == "cancelled":
            reason = "The print of %s was %s." % (
                job["name"], snap["error"] or "cancelled by a person (hostd cancel)")
            log.info("job %s: %s", job["id"], reason)
            return self._filing(job, reason, state=J.CANCELLED)
        error = snap["error"] or slot.printer.last_error
        self._hold(slot, "the print of %s ended abnormally (%s)" % (job["name"], error))
        return self._failing(job, "The printer %s stopped the print: %s. The printer is held: "
                                  "clear the bed, resume the printer, then `hostd requeue %s`."
                             % (slot.name, error, job["id"]), "printer.error")

    def _hold(self, slot, reason):
        """Start nothing on ``slot`` until a person has looked at its bed and resumed it."""
        slot.paused = True
        slot.held = reason + ": clear the bed, then resume the printer"
        with self._full_ok():
            self.store.set_printer(slot.name, paused=1, held=slot.held)
        log.warning("printer %s held: %s", slot.name, slot.held)

    def _interrupt(self, slot, reason):
        job = self.store.get(slot.job_id)
        snap = slot.link_job.snapshot() if slot.link_job is not None else {}
        line = snap.get("last_confirmed_line", job["last_line"])
        self._unspool(slot.job_id)
        slot.job_id, slot.link_job = None, None
        self.store.update(job["id"], last_line=line)
        self._hold(slot, "the print of %s was interrupted (%s)" % (job["name"], reason))
        text = ("The print of %s was interrupted: %s (last confirmed line %d). Check the bed, "
                "then print it again with `hostd requeue %s`." % (job["name"], reason, line,
                                                                   job["id"]))
        log.warning("job %s: %s", job["id"], text)
        self._to_failed(dict(job, last_line=line), text, state=J.INTERRUPTED,
                        code="job.interrupted")

    # -- endings -----------------------------------------------------------------------------------

    def _fail(self, job, reason, code=None):
        self._failing(job, reason, code)()

    def _failing(self, job, reason, code=None):
        # People know the files by the names they dropped, not by their claimed paths.
        reason = reason.replace(str(job["input_path"]), job["rel_path"])
        if job["sidecar_path"]:
            dropped = PurePosixPath(job["rel_path"])
            reason = reason.replace(str(job["sidecar_path"]),
                                    str(dropped.with_name(dropped.stem + ".yaml")))
        reason = bounded(reason)
        log.warning("job %s failed: %s", job["id"], reason)
        return self._filing(job, reason, state=J.FAILED, code=code or "job.failed")

    def _to_failed(self, job, reason, state=None, code=None):
        """Move the input to failed/ beside NAME.error.txt and record ``state``."""
        self._filing(job, reason, state, code)()

    def _filing(self, job, reason, state=None, code=None):
        """The move of :meth:`_to_failed`; returns the call that records ``state``."""
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

    # -- status -------------------------------------------------------------------------------------

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

    def _holding_prints(self):
        """Whether a printer holds a job: printing, or ended and its outcome not yet
        recorded (asked from the watchdog's thread)."""
        return any(s.job_id is not None for s in self.slots)

    def _heartbeat(self, state="running"):
        with self._share_ok():
            self._twin_seen(self.farm.renew_lease(state), time.monotonic())
            self._share_back()
            if state == "running":
                self.farm.release_dead()
        status = self.status(state)
        if self._share is None:
            with self._share_ok():
                self.farm.publish_status(status)
        with self._full_ok():
            for slot in self.slots:
                self.store.set_printer(slot.name, state=slot.state)
        busy = [s for s in status["printers"] if s["job"]]
        self.notify.status("%d printing, %d queued, %d planning%s%s" % (
            len(busy), status["queue_length"], len(status["planning"]),
            "; job database full" if self._full is not None else "",
            "; share unreachable" if self._share is not None else ""))


def run(config):
    """Run the daemon in this process until SIGTERM/SIGINT; returns the exit status."""
    daemon = Daemon(config)
    old = {s: signal.signal(s, daemon.request_stop) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        return daemon.run()
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
