"""The terminal commands' door into a running daemon (``hostd requeue/cancel/pause/resume``).

The CLI (and the web) writes a request into the job store's ``control`` table:
``store.request(action, target)``, with ``action`` one of :data:`ACTIONS` and ``target`` a job
id, a printer's name or (reorder) a JSON list of job ids. The run loop calls
:meth:`Control.answer` every tick, which carries each out and writes the answer
(``ok``, text) that ``store.wait_answer`` returns.

An object handed the configuration, the job store, the printers, the plans, the farm, the
routing rules, the endings and the printers' room (which holds a printer until its bed
is clear).
"""

import logging
import os
import stat
from pathlib import Path

from hostd import farm as farm_mod
from hostd import jobs as J
from hostd.errors import HostdError

log = logging.getLogger("hostd.daemon")


ACTIONS = ("cancel", "requeue", "approve", "pause", "resume", "estop", "reorder", "clear")


class Control:
    """The answers to requests from the terminal commands and the web."""

    def __init__(self, config, store, slots, plans=None, farm=None, routes=None, endings=None,
                 printing=None):
        self.config = config
        self.store = store
        self.slots = slots
        self.plans = plans
        self.farm = farm
        self.routes = routes
        self.endings = endings
        self.printing = printing

    def answer(self):
        """Carry out every pending request and write its answer."""
        for req in self.store.pending_requests():
            try:
                if req["action"] not in ACTIONS:
                    raise HostdError("unknown request %r" % req["action"],
                                     code="control.unknown_action",
                                     fix="ask one of: " + ", ".join(ACTIONS))
                ok, result = True, getattr(self, req["action"])(req["target"])
            except HostdError as exc:
                ok, result = False, exc.text()
            except Exception as exc:  # answer the CLI whatever happens, then carry on
                log.exception("control request %s failed", req)
                ok, result = False, "internal error: %s" % exc
            self.store.answer(req["id"], ok, result)

    def _slot(self, name):
        for slot in self.slots:
            if slot.name == name:
                return slot
        raise HostdError("no printer %r on node %s" % (name, self.config.node_id),
                         code="control.unknown_printer",
                         fix="printers here: " + ", ".join(s.name for s in self.slots))

    def cancel(self, job_id):
        job = self.store.require(job_id)
        if job["state"] in J.FINISHED:
            raise HostdError("job %s is already %s" % (job["id"], job["state"]),
                             code="control.finished")
        if job["state"] == J.PRINTING:
            for slot in self.slots:
                if slot.job_id == job["id"]:
                    self._cancel_print(slot, job)
            return "cancelling %s: the printer runs its cancel script" % job["id"]
        self.plans.cancel(job["id"])
        self.endings.to_failed(job, "The job %s was cancelled by a person (hostd cancel)."
                               % job["name"], state=J.CANCELLED)
        return "cancelled %s" % job["id"]

    def _cancel_print(self, slot, job):
        """Cancel the print on ``slot``, unless it ended already: the page cancels the
        printer itself before it asks (a full job database must not keep a person from
        stopping a print), and its cancel may have ended the print by now."""
        from hostd.printer import PrinterError
        link_job = slot.link_job
        try:
            slot.printer.cancel()
        except PrinterError:
            result = link_job.snapshot()["result"] if link_job is not None else None
            if result is None:
                raise
            if result != "cancelled":
                raise HostdError("the print of %s ended (%s) before the cancel reached the "
                                 "printer" % (job["name"], result),
                                 code="control.finished") from None

    def _shown(self, path, job):
        """A path of ``job``'s as people know it: failed/NAME, else the dropped name."""
        path = Path(path)
        if path.parent == Path(self.config.failed_dir):
            return "failed/" + path.name
        return job["rel_path"]

    def _regular(self, path, job, what):
        """Whether ``path`` exists; a requeue reads only regular files from the share (a
        symbolic link could point anywhere the daemon may read)."""
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            return False
        if not stat.S_ISREG(mode):
            raise HostdError("not requeued: %s of %s (%s) is not a regular file (a symbolic "
                             "link, a folder or a device)" % (what, job["id"],
                                                             self._shown(path, job)),
                             code="control.not_regular",
                             fix="put the file itself there, then requeue again")
        return True

    def requeue(self, job_id):
        job = self.store.require(job_id)
        if job["state"] not in J.FINISHED:
            raise HostdError("job %s is %s, not finished" % (job["id"], job["state"]),
                             code="control.active", fix="cancel it first")
        src = Path(job["input_path"])
        # The sidecar it came with, or one a person wrote beside it since (NAME.error.txt
        # says so: a changed smooth_mm or size_mm is how most failed plans are fixed).
        side_src = Path(job["sidecar_path"] or src.with_name(src.stem + ".yaml"))
        if not self._regular(src, job, "the input"):
            raise HostdError("not requeued: the input of %s is gone (%s)"
                             % (job["id"], self._shown(src, job)),
                             code="control.input_missing", fix="drop the file again")
        has_side = self._regular(side_src, job, "the sidecar")
        folder = self.farm.claim_dir / (job["target"] or farm_mod.ROOT_TARGET)
        folder.mkdir(parents=True, exist_ok=True)
        dest = farm_mod.unique_path(folder / src.name)
        os.rename(src, dest)
        side = None
        if has_side:
            side = dest.with_name(dest.stem + ".yaml")
            os.rename(side_src, side)
        err = src.with_name(src.stem + ".error.txt")
        if err.exists():
            os.unlink(err)   # the reason is kept in the job's events
        self.store.set_state(job["id"], J.QUEUED, "requeued by a person", input_path=str(dest),
                             sidecar_path=str(side) if side else None, error=None,
                             error_code=None, decision=None, copies_done=0, progress=0.0,
                             finished_at=None)
        # The sidecar may have changed (a profile, copies, priority): read it again, as
        # intake does, so the job is planned with what the file now says.
        if self._retarget(self.store.get(job["id"]), side):
            # Told as the job's failure tells it: by the names people dropped.
            raise HostdError("not requeued: %s" % self.store.get(job["id"])["error"],
                             code="control.requeue_refused")
        return "requeued %s" % job["id"]

    def approve(self, job_id):
        job = self.store.require(job_id)
        if job["state"] != J.READY or not job["decision"]:
            raise HostdError("job %s does not wait for a decision (it is %s)"
                             % (job["id"], job["state"]), code="control.no_decision")
        self.store.set_state(job["id"], J.READY, "a person chose to print it anyway",
                             decision=None)
        return "approved %s: it prints on the next free printer" % job["id"]

    def _retarget(self, job, side):
        """Re-read ``job``'s sidecar and take its profile, copies and priority; a sidecar
        that is wrong, or names a profile no printer here uses, fails the job again.
        Returns the reason it failed, or None."""
        from pipeline.errors import PipelineError
        from pipeline.input.sidecar import load_sidecar
        try:
            sidecar = load_sidecar(side) if side else None
        except PipelineError as exc:
            self.endings.fail(job, exc.text(), exc.code)
            return exc.text()
        profile = self.routes.profile_for(job["target"], sidecar)
        self.store.update(job["id"], profile=profile,
                          priority=sidecar.priority if sidecar else 0,
                          copies=sidecar.copies if sidecar else 1)
        job = self.store.get(job["id"])
        if not any(self.routes.eligible(s, job) for s in self.slots):
            reason = self.routes.no_printer_text(profile, job["target"])
            self.endings.fail(job, reason, "job.no_printer")
            return reason
        return None

    def clear(self, name):
        """A person says the bed of printer ``name`` is clear: it takes the next job."""
        slot = self._slot(name)
        if slot.job_id is not None:
            raise HostdError("printer %s is printing %s: its bed is not clear"
                             % (name, slot.job_id), code="control.printing",
                             fix="wait for the print to end, or cancel it first")
        if slot.held is None:
            return "%s does not wait for its bed to be cleared" % name
        self.printing.clear(slot)
        return "bed of %s is clear: it takes the next job" % name

    def pause(self, name):
        slot = self._slot(name)
        slot.paused = True
        self.store.set_printer(name, paused=1)
        if slot.job_id is not None:
            slot.printer.pause()
            self.store.event(slot.job_id, "paused", "paused by a person")
        return "paused %s" % name

    def resume(self, name):
        slot = self._slot(name)
        slot.paused = False
        slot.held = None
        self.store.set_printer(name, paused=0, held=None)
        if slot.job_id is not None:
            slot.printer.resume()
            self.store.event(slot.job_id, "resumed", "resumed by a person")
        elif slot.state == "error":
            # A printer that stopped answering and came back stays in error until its
            # link starts over: a person resuming it is the sign to reconnect.
            slot.error = None
            slot.connect_async()
            return "resumed %s: reconnecting" % name
        return "resumed %s" % name


    def estop(self, name):
        # The web writes M112 itself when it runs in this process; a second one is harmless
        # and covers requests from another process.
        from hostd.printer import PrinterError
        slot = self._slot(name)
        if slot.printer is None:
            raise HostdError("printer %s is not connected" % name, code="control.disconnected")
        try:
            slot.printer.estop()
        except PrinterError as exc:
            raise HostdError("emergency stop of %s failed: %s" % (name, exc),
                             code="control.estop_failed") from None
        slot.paused = True           # a halted printer takes no new job until resumed
        self.store.set_printer(name, paused=1)
        if slot.job_id is not None:
            self.store.event(slot.job_id, "estop", "emergency stop (M112) by a person")
        log.warning("printer %s: emergency stop by a person", name)
        return "emergency stop sent to %s (M112); reset the printer, then resume" % name

    def reorder(self, order_json):
        """``order_json``: job ids, first to print first; the rest keep their order after."""
        import json
        order = json.loads(order_json)
        queue = sorted(self.store.list([J.QUEUED, J.PLANNING, J.READY]),
                       key=lambda j: (-j["priority"], j["seq"]))
        by_id = {j["id"]: j for j in queue}
        ids = [i for i in order if i in by_id] + [j["id"] for j in queue if j["id"] not in order]
        for rank, job_id in enumerate(ids):
            priority = len(ids) - rank
            if by_id[job_id]["priority"] != priority:
                self.store.update(job_id, priority=priority)
        return "queue order: " + ", ".join(ids)
