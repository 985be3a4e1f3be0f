"""Planning in worker processes, so the GIL never stalls serial streaming.

Each plan runs in its own child (``python -m hostd.planning``), which loads its
libraries and then limits its address space (RLIMIT_AS) and CPU time (RLIMIT_CPU);
the parent also kills it after ``time_limit_s`` of wall time, and on Linux the kernel
kills it when the thread that started it (the daemon's loop) dies. A plan that crashes,
runs out of memory or runs away fails its own job only. The child writes
``result.json`` into its output folder: ``{"ok": true}`` or the error's dict.
"""

import errno
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from hostd.outputs import disk_text

_REPO = str(Path(__file__).resolve().parents[1])


class PlanProcess:
    """One running plan: ``poll()`` -> None while running, else a result dict."""

    def __init__(self, job_id, input_path, profile, outdir, time_limit_s, memory_mb,
                 keep=None):
        self.job_id = job_id
        self.outdir = Path(outdir)
        self.time_limit_s = float(time_limit_s)
        self.started = time.monotonic()
        args = json.dumps({"input": str(input_path), "profile": profile, "outdir": str(outdir),
                           "memory_mb": int(memory_mb), "cpu_s": int(time_limit_s) + 5,
                           "parent_pid": os.getpid(), "keep": keep and str(keep)})
        env = dict(os.environ)
        env["PYTHONPATH"] = _REPO + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        # Few threads per child: several plans must not starve the streaming thread.
        env.setdefault("OMP_NUM_THREADS", "1")
        env.setdefault("OPENBLAS_NUM_THREADS", "1")
        self.proc = subprocess.Popen([sys.executable, "-m", "hostd.planning", args],
                                     stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, env=env, start_new_session=True)
        self.pid = self.proc.pid

    def poll(self):
        code = self.proc.poll()
        if code is None:
            if time.monotonic() - self.started > self.time_limit_s:
                self.kill()
                return {"ok": False, "code": "plan.time_limit",
                        "text": "planning took longer than the limit of %.0f s and was stopped"
                                % self.time_limit_s,
                        "fix": "use a smaller or simpler height field, or raise "
                               "planning.time_limit_s in hostd.yaml"}
            return None
        stderr = self.proc.stderr.read().decode("utf-8", "replace") if self.proc.stderr else ""
        self.proc.stderr.close()
        result = _read_result(self.outdir / "result.json")
        if result is not None:
            return result
        if code < 0:
            how = "was killed by signal %d" % -code
        else:
            how = "exited with status %d" % code
        tail = stderr.strip().splitlines()[-1:] if stderr.strip() else []
        # OpenBLAS exits on its own when a buffer will not map: that too is the limit.
        memory = "MemoryError" in stderr or "Memory allocation still failed" in stderr
        return {"ok": False, "code": "plan.memory_limit" if memory else "plan.crashed",
                "text": "the planning process %s%s" % (
                    "ran out of memory (limit reached)" if memory else how,
                    (": " + tail[0]) if tail and not memory else ""),
                "fix": "raise planning.memory_mb in hostd.yaml or use a smaller input"
                       if memory else "try again with `hostd requeue`; report it if it repeats"}

    def stage(self):
        """What the plan is doing, from the child's ``stage.json``: e.g. ``flatten, 23 s``."""
        name = (_read_result(self.outdir / "stage.json") or {}).get("stage") or "starting"
        return "%s, %d s" % (name, time.monotonic() - self.started)

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        if self.proc.stderr and not self.proc.stderr.closed:
            self.proc.stderr.close()


def _read_result(path):
    from hostd import share
    from hostd.errors import HostdError
    try:
        result = share.read_json(path)
    except (OSError, ValueError, HostdError):
        return None
    return result if isinstance(result, dict) else None


def _limit(memory_mb, cpu_s):
    import resource
    if memory_mb:
        limit = int(memory_mb) * 1024 * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    if cpu_s:
        resource.setrlimit(resource.RLIMIT_CPU, (int(cpu_s), int(cpu_s) + 2))


def plan_result(plan):
    """The job's verdict on a finished plan: a plan that cannot print (its flat layout
    folds, or the relief asked for cannot form) fails its job with the reasons; its
    outputs stay for a person. A plan outside the profile's printable limits is ready,
    and the daemon holds it for a person's decision (read from its report)."""
    from pipeline.problems import BLOCKING
    if not plan.blocked:
        return {"ok": True}
    worst = next(p for p in plan.problems if p["code"] in BLOCKING)
    text = "; ".join(p["message"] for p in plan.problems)
    return {"ok": False, "code": worst["code"], "text": "planned but not printable: " + text,
            "fix": worst["fix"] + " (the outbox has the pictures that show where)"}


def _die_with_parent(parent_pid):
    """Have the kernel kill this plan when the daemon that started it dies.

    A daemon killed outright (kill -9, a crash; outside systemd, which kills the
    whole unit) would otherwise leave its plans running for up to their time limit,
    next to the plans the restarted daemon starts for the same jobs: on a 1 GB
    printer host that is how one out-of-memory kill becomes several. Linux only
    (prctl PR_SET_PDEATHSIG); elsewhere the plan runs to its limits.
    """
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal
    pr_set_pdeathsig = 1
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0) != 0:
        return
    if parent_pid and os.getppid() != parent_pid:   # it died before prctl took effect
        os._exit(3)


def _disk_full(outdir):
    """The verdict on a plan whose outputs did not fit on the disk.

    Its partial outputs go first, which also makes room for the verdict itself.
    """
    for path in Path(outdir).iterdir():
        if path.is_file():
            path.unlink()
    return {"ok": False, "code": "plan.disk_full",
            "text": "the outbox's disk is full: the plan's outputs did not fit (%s once they "
                    "were removed; a 150-175 mm part needs 15-30 MB)" % disk_text(outdir),
            "fix": "free space on that disk (finished jobs' folders in the outbox can go) or "
                   "set outbox_dir to a larger disk, then `hostd requeue` the job"}


def _stage_writer(outdir):
    """The pipeline's progress callback in the child: each stage's name and message into
    ``stage.json``, which the daemon shows while the plan runs."""
    from hostd.outputs import atomic_write, json_text

    def progress(stage, message):
        try:
            atomic_write(Path(outdir) / "stage.json", json_text({"stage": stage,
                                                                 "message": message}))
        except OSError:
            pass   # progress is a courtesy; the plan goes on
    return progress


def child_main(argv):
    args = json.loads(argv[0])
    _die_with_parent(args.get("parent_pid"))
    try:
        os.nice(5)   # the streaming thread in the parent comes first
    except OSError:
        pass
    outdir = Path(args["outdir"])
    # Loaded before the limit: OpenBLAS, loading under an address-space limit it cannot
    # get its buffer within, retries the mmap forever (the plan spins to its CPU limit
    # instead of failing); loaded, it allocates no more, and the plan's own arrays meet
    # the limit as a MemoryError.
    from hostd import planner
    from hostd.outputs import atomic_write, json_text
    from pipeline.errors import PipelineError
    from pipeline.profiles.profile import load_profile
    _limit(args.get("memory_mb"), args.get("cpu_s"))
    try:
        profile = load_profile(args["profile"])
        result = plan_result(planner.run(args["input"], profile, outdir,
                                         progress=_stage_writer(outdir), keep=args.get("keep")))
    except PipelineError as exc:
        result = dict(exc.to_dict(), ok=False)
    except MemoryError:
        result = {"ok": False, "code": "plan.memory_limit",
                  "text": "planning ran out of memory (limit %s MB)" % args.get("memory_mb"),
                  "fix": "raise planning.memory_mb in hostd.yaml or use a smaller input"}
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        result = _disk_full(outdir)
    (outdir / "stage.json").unlink(missing_ok=True)   # the plan's progress, not an output
    atomic_write(outdir / "result.json", json_text(result))
    return 0 if result["ok"] else 2


if __name__ == "__main__":
    raise SystemExit(child_main(sys.argv[1:]))
