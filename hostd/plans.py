"""The node's plans: which queued job is planned next, the plan processes running, and
what each leaves in its job's outbox (a ready plan, or the files of a failed one).

An object with its own state, handed what it needs from the daemon: the job store,
whether a job may be planned here, how a job fails, and how to write a courtesy update
that must never stop the loop (the job store may be full).
"""

import logging
import shutil
import time
from pathlib import Path

from hostd import jobs as J
from hostd import share
from hostd.errors import HostdError
from hostd.farm import PlanCache, file_hash, plan_key
from hostd.kept import Kept
from hostd.planning import PlanProcess
from hostd.reports import decision, report_in
from hostd.watcher import name_problem

log = logging.getLogger("hostd.daemon")

# A running plan's stage goes to the store this often (each write lands on the SD card).
STAGE_S = 2.0


class Plans:
    """Plan processes by job id; ``job_id in plans``, ``len(plans)``, ``sorted(plans)``.

    may_plan(job) -> None, or why no printer here can print it; fail(job, text, code);
    quietly() -> a context in which a failed write is noted, not raised.
    """

    def __init__(self, config, store, may_plan, fail, quietly):
        self.config = config
        self.store = store
        self.cache = PlanCache(Path(config.outbox_dir) / ".cache")
        self.kept = Kept(config.state_dir)
        self._may_plan, self._fail, self._quietly = may_plan, fail, quietly
        self._running = {}            # job id -> PlanProcess
        self._profile_hashes = {}

    def __contains__(self, job_id):
        return job_id in self._running

    def __iter__(self):
        return iter(list(self._running))

    def __len__(self):
        return len(self._running)

    def start(self):
        """Start plans for queued jobs, in order, while workers are free; a plan found in
        the cache makes its job ready at once."""
        from pipeline import __version__
        from pipeline.errors import PipelineError
        for job in self.store.next_in_order(J.QUEUED):
            if len(self._running) >= self.config.planning.workers:
                return
            if job["id"] in self._running:   # started while its state could not be recorded
                continue
            # Only the profiles this node's printers use are ever read: a job's profile
            # comes from a sidecar anyone with the drop folder can write.
            why_not = self._may_plan(job)
            if why_not:
                self._fail(job, why_not, "job.no_printer")
                continue
            try:
                digest = job["input_hash"] or file_hash(job["input_path"])
                key = plan_key(digest, job["sidecar_path"], self._profile_hash(job["profile"]),
                               __version__)
            except PipelineError as exc:
                self._fail(job, exc.text(), exc.code)
                continue
            except OSError as exc:
                self._fail(job, "cannot read the input: %s" % exc, "job.unreadable")
                continue
            except HostdError as exc:
                if not share.refused(exc):
                    raise
                self._fail(job, "cannot read the input: %s" % exc.text(), "job.unreadable")
                continue
            self.store.update(job["id"], input_hash=digest, plan_key=key)
            job.update(input_hash=digest, plan_key=key)
            # Only a plan this node made and kept is printed: the share's copy alone may
            # have been edited by anyone who can write the share.
            if self.cache.get(key) and self.kept.folder(key):
                self._ready(job, "plan found in the cache")
                continue
            outdir = self.cache.staging(job["id"])
            proc = PlanProcess(job["id"], job["input_path"], job["profile"], outdir,
                               self.config.planning.time_limit_s, self.config.planning.memory_mb,
                               keep=self.kept.staging(job["id"]))
            self._running[job["id"]] = proc
            self.store.set_state(job["id"], J.PLANNING, "planning in process %d" % proc.pid,
                                 stage=proc.stage())

    def reap(self):
        """Take the results of finished plans; tell the store the stage of running ones."""
        now = time.monotonic()
        for job_id, proc in list(self._running.items()):
            result = proc.poll()
            if result is None:
                if now >= getattr(proc, "stage_due", 0.0):
                    proc.stage_due = now + STAGE_S
                    with self._quietly():   # a courtesy to the page, never a reason to stop
                        self.store.update(job_id, stage=proc.stage())
                continue
            del self._running[job_id]
            job = self.store.get(job_id)
            if result.get("ok"):
                result = self._keep(job)
            if result.get("ok"):
                self.cache.store(proc.outdir, job["plan_key"], Path(job["input_path"]).stem)
                self._ready(job, "planned in %.1f s" % (time.monotonic() - proc.started))
                self.kept.prune({j["plan_key"] for j in self.store.list(J.ACTIVE)})
            else:
                self.kept.discard(job_id)
                self._failed(job, proc, result)

    def _keep(self, job):
        """Make the finished plan of ``job`` the node's own copy: a result dict."""
        try:
            self.kept.keep(job["id"], job["plan_key"])
            return {"ok": True}
        except OSError as exc:
            return {"ok": False, "code": "plan.not_kept",
                    "text": "the plan's G-code could not be kept in %s: %s" % (
                        self.kept.root, exc.strerror or exc),
                    "fix": "free space on the node's own disk (state_dir), then `hostd requeue` "
                           "the job"}

    def cancel(self, job_id):
        """Stop the plan of ``job_id``, if one runs; True if it did."""
        proc = self._running.pop(job_id, None)
        if proc:
            proc.kill()
            self.kept.discard(job_id)
        return proc is not None

    def stop_all(self):
        """Kill every running plan; returns their job ids."""
        ids = list(self._running)
        for proc in self._running.values():
            proc.kill()
        self._running.clear()
        return ids

    def _failed(self, job, proc, result):
        # Whatever the plan wrote (an error file, or the pictures of a plan that is not
        # printable) goes to the job's outbox for a person.
        outbox = self._outbox(job, fresh=True)
        for f in Path(proc.outdir).iterdir():
            if f.is_file() and f.name != "result.json":
                shutil.copy2(f, outbox / f.name)
        shutil.rmtree(proc.outdir, ignore_errors=True)
        text = result.get("text") or result.get("message") or "planning failed"
        if result.get("fix") and "Fix:" not in text:
            text += ". Fix: " + result["fix"]
        self.store.update(job["id"], outbox=str(outbox))
        self._fail(self.store.get(job["id"]), text, result.get("code"))

    def _outbox(self, job, fresh=False):
        """The job's outbox folder; ``fresh`` empties it first: each attempt's outputs
        replace the last attempt's as a whole (a requeued job shows only what it made)."""
        d = Path(self.config.outbox_dir) / job["id"]
        if fresh and d.is_dir():
            for f in d.iterdir():
                if f.is_file() or f.is_symlink():
                    f.unlink()
        d.mkdir(parents=True, exist_ok=True)
        return d

    def _ready(self, job, message):
        outbox = self._outbox(job, fresh=True)
        self.cache.export(job["plan_key"], outbox, Path(job["name"]).stem if not
                          name_problem(job["name"]) else Path(job["input_path"]).stem)
        wait = decision(report_in(self.kept.folder(job["plan_key"])))
        self.store.set_state(job["id"], J.READY, message + (". " + wait if wait else ""),
                             outbox=str(outbox), decision=wait)
        log.info("job %s: %s ready (%s), outputs in %s", job["id"], job["name"], message, outbox)

    def gcode(self, job):
        """The G-code a printer runs for ``job``: the node's own copy of its plan, or None."""
        return self.kept.gcode(job["plan_key"])

    def _profile_hash(self, name):
        if name not in self._profile_hashes:
            from pipeline.profiles.dump import profile_hash
            from pipeline.profiles.profile import load_profile
            self._profile_hashes[name] = profile_hash(load_profile(name))
        return self._profile_hashes[name]
