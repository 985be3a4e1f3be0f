"""The printers' room: ready jobs handed to idle printers, prints followed to their end, and
a printer held after every print until a person says its bed is clear.

After a print, finished or not, the part (or what is left of it) is on the bed: the next
job must not start on top of it. So the printer waits (``slot.held`` says why, the store
keeps it across a restart) until a person says the bed is clear, unless its profile takes
the finished part off by itself (``bed_clear: auto`` with ``gcode.clear_bed``, and the
print's G-code ends with it). A print that did not finish always waits for a person; one
that failed on the printer also pauses it.

An object handed the configuration, the job store, the printers (:class:`hostd.slot.Slot`),
the routing rules, the endings and the outages. Each printer's link streams on a thread
of its own; this room only starts, watches and records.
"""

import logging
import os
import shutil
import time

from hostd import jobs as J
from hostd.farm import archive_done
from hostd.feed import job_feed

log = logging.getLogger("hostd.daemon")
# A print's progress goes to the store this often, not every tick: each write appends pages
# to the WAL, and 20 a second were 80-90 kB/s of writes on a host's SD card.
PROGRESS_S = 2.0
RECONNECT_S = 5.0
TAIL_BYTES = 64 * 1024     # where a plan's G-code ends with its clear_bed block, if it has one


class Printing:
    """Prints on this node's printers."""

    def __init__(self, config, store, slots, routes, endings, outages, plans):
        self.config = config
        self.store = store
        self.slots = slots
        self.routes = routes
        self.endings = endings
        self.outages = outages
        self.plans = plans
        self._next_reconnect = 0.0

    def slot(self, name):
        """The printer called ``name``, or None."""
        return next((s for s in self.slots if s.name == name), None)

    def connect(self):
        """Take each printer's hold from the store and connect it in the background."""
        rows = self.store.printers()
        for slot in self.slots:
            # A hold outlives a restart: the print is still on that bed. A pause came with
            # it only after a fault (see hold).
            row = rows.get(slot.name, {})
            slot.held = row.get("held")
            slot.paused = slot.held is not None and bool(row.get("paused", 1))
            self.store.set_printer(slot.name, state="connecting", paused=int(slot.paused),
                                   job_id=None)
            slot.connect_async()

    def busy(self):
        """Whether a printer holds a job: printing, or ended and its outcome not yet
        recorded (asked from the watchdog's thread)."""
        return any(s.job_id is not None for s in self.slots)

    def gcode(self, job):
        """The G-code a printer runs for ``job``: the node's own copy, never the share's."""
        return self.plans.gcode(job)

    # -- starting ------------------------------------------------------------------------------

    def dispatch(self):
        now = time.monotonic()
        if now >= self._next_reconnect:
            self._next_reconnect = now + RECONNECT_S
            for slot in self.slots:
                if slot.state in ("disconnected",) and slot.job_id is None:
                    slot.connect_async()
        held = {s.job_id for s in self.slots}
        for job in self.store.next_in_order(J.READY):
            if job["id"] in held or job["decision"]:   # started unrecorded, or a person decides
                continue
            for slot in self.slots:
                if slot.available() and self.routes.eligible(slot, job):
                    self.start(slot, job)
                    break

    def start(self, slot, job):
        from hostd.printer import PrinterError
        gcode = self.gcode(job)
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
            self.unspool(job["id"])
            return
        slot.job_id = job["id"]
        slot.clears_bed = self._clears_bed(slot, gcode)
        self.store.set_state(job["id"], J.PRINTING, "printing on %s (copy %d of %d)%s" % (
            slot.name, job["copies_done"] + 1, job["copies"],
            "; " + rate.note if rate.note else ""), printer=slot.name,
            started_at=job["started_at"] or time.time(), progress=0.0)
        self.store.set_printer(slot.name, job_id=job["id"])
        log.info("job %s: printing %s on %s (copy %d of %d)", job["id"], job["name"], slot.name,
                 job["copies_done"] + 1, job["copies"])

    def _clears_bed(self, slot, gcode):
        """Whether the print of ``gcode`` takes its part off the bed by itself: the printer's
        profile says ``bed_clear: auto`` and the file ends with that profile's clear_bed
        G-code (a plan made before the profile said so does not)."""
        from pipeline.errors import PipelineError
        from pipeline.profiles.profile import load_profile
        from pipeline.profiles.schema import CLEAR_BED_MARK
        try:
            profile = load_profile(slot.config.profile)
        except PipelineError:
            return False
        if profile.bed_clear != "auto":
            return False
        block = CLEAR_BED_MARK + "\n" + profile.render_gcode("clear_bed").rstrip("\n") + "\n"
        try:
            with open(gcode, "rb") as f:
                f.seek(max(0, os.fstat(f.fileno()).st_size - TAIL_BYTES - len(block)))
                tail = f.read().decode("utf-8", "replace")
        except OSError:
            return False
        return block in tail

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

    def unspool(self, job_id):
        (self.config.spool_dir / (job_id + ".gcode")).unlink(missing_ok=True)

    # -- following ---------------------------------------------------------------------------

    def follow(self):
        for slot in self.slots:
            if slot.job_id is None:
                continue
            snap = slot.link_job.snapshot()
            if snap["result"] is None:
                self._progress(slot, snap)
                continue
            if slot.ending is None:
                if self.outages.share is not None:
                    continue   # the input is filed once the share is back
                slot.ending = self._ending(slot, snap)
            slot.ending()   # may find the store full: the slot keeps the job until it is recorded
            self.unspool(slot.job_id)
            slot.job_id = slot.link_job = slot.ending = None
            self.store.set_printer(slot.name, job_id=None)

    def _progress(self, slot, snap):
        now = time.monotonic()
        if now < slot.progress_due:
            return
        slot.progress_due = now + PROGRESS_S
        total = snap["total"] or 0
        progress = snap["confirmed"] / total if total else 0.0
        with self.outages.full_ok():   # the page shows live progress from the printer
            self.store.update(slot.job_id, progress=round(progress, 4),
                              last_line=snap["last_confirmed_line"])

    def _ending(self, slot, snap):
        """File the input of a finished print; returns the call that records the outcome."""
        job = self.store.get(slot.job_id)
        if snap["result"] == "done":
            return self._done(slot, job, snap)
        if snap["result"] == "cancelled":
            how = snap["error"] or "cancelled by a person (hostd cancel)"
            reason = "The print of %s was %s." % (job["name"], how)
            log.info("job %s: %s", job["id"], reason)
            self.wait_for_person(slot, "the print of %s was %s" % (job["name"], how))
            return self.endings.filing(job, reason, state=J.CANCELLED)
        error = snap["error"] or slot.printer.last_error
        self.hold(slot, "the print of %s ended abnormally (%s)" % (job["name"], error))
        return self.endings.failing(job, "The printer %s stopped the print: %s. The printer is "
                                         "held: clear the bed, resume the printer, then `hostd "
                                         "requeue %s`." % (slot.name, error, job["id"]),
                                    "printer.error")

    def _done(self, slot, job, snap):
        copies = job["copies_done"] + 1
        if not slot.clears_bed:
            self.wait_for_person(slot, "the print of %s finished%s" % (
                job["name"], " (copy %d of %d)" % (copies, job["copies"])
                if job["copies"] > 1 else ""))
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

    # -- holding -------------------------------------------------------------------------------

    def wait_for_person(self, slot, reason):
        """Start nothing on ``slot`` until a person says its bed is clear (:meth:`clear`)."""
        slot.held = "%s: take it off the bed, then say the bed is clear (Bed is clear on the " \
                    "page, or `hostd clear %s`)" % (reason, slot.name)
        with self.outages.full_ok():
            self.store.set_printer(slot.name, held=slot.held)
        log.info("printer %s waits for a person: %s", slot.name, slot.held)

    def hold(self, slot, reason):
        """Start nothing on ``slot`` until a person has looked at its bed and resumed it."""
        slot.paused = True
        slot.held = reason + ": clear the bed, then resume the printer"
        with self.outages.full_ok():
            self.store.set_printer(slot.name, paused=1, held=slot.held)
        log.warning("printer %s held: %s", slot.name, slot.held)

    def clear(self, slot):
        """A person says ``slot``'s bed is clear: it takes the next job (a pause that came
        with a hold goes with it)."""
        slot.held = None
        slot.paused = False
        self.store.set_printer(slot.name, paused=0, held=None)
        log.info("printer %s: a person says its bed is clear", slot.name)

    def interrupt(self, slot, reason):
        job = self.store.get(slot.job_id)
        snap = slot.link_job.snapshot() if slot.link_job is not None else {}
        line = snap.get("last_confirmed_line", job["last_line"])
        self.unspool(slot.job_id)
        slot.job_id, slot.link_job = None, None
        self.store.update(job["id"], last_line=line)
        self.hold(slot, "the print of %s was interrupted (%s)" % (job["name"], reason))
        text = ("The print of %s was interrupted: %s (last confirmed line %d). Check the bed, "
                "then print it again with `hostd requeue %s`." % (job["name"], reason, line,
                                                                   job["id"]))
        log.warning("job %s: %s", job["id"], text)
        self.endings.to_failed(dict(job, last_line=line), text, state=J.INTERRUPTED,
                               code="job.interrupted")

    def stop(self, deadline):
        """Stop every print (cancel script: heaters off, lift, motors off) and record it
        interrupted, waiting for the links until ``deadline`` (time.monotonic, s)."""
        for slot in self.slots:
            if slot.job_id is not None and slot.link_job is not None:
                try:
                    slot.printer.cancel()
                except Exception as exc:
                    log.warning("printer %s: cancel failed: %s", slot.name, exc)
        for slot in self.slots:
            if slot.job_id is not None:
                if slot.link_job is not None:
                    slot.link_job.wait(max(0.1, deadline - time.monotonic()))
                # With the job database full, the next start records what is left unrecorded.
                if self.outages.full is None:
                    with self.outages.full_ok():
                        self.interrupt(slot, "the daemon was stopped during the print")
