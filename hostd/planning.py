"""Planning in worker processes, so the GIL never stalls serial streaming.

Each plan runs in its own child, forked by the planning server
(:mod:`hostd.planserver`, which has the libraries loaded) or, where that cannot start,
run as ``python -m hostd.planning``, which loads them itself; the child then limits its
address space (RLIMIT_AS) and CPU time (RLIMIT_CPU);
the parent also kills it after ``time_limit_s`` of wall time, and on Linux the kernel
kills it when the thread that started it (the daemon's loop) dies. A plan that crashes,
runs out of memory or runs away fails its own job only. The child writes
``result.json`` into its output folder: ``{"ok": true}`` or the error's dict.
"""

import errno
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
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
        self.proc = _server().start(args) if sys.platform.startswith("linux") else None
        if self.proc is None:
            self.proc = subprocess.Popen([sys.executable, "-m", "hostd.planning", args],
                                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                         stderr=subprocess.PIPE, env=_child_env(),
                                         start_new_session=True)
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


def _child_env():
    env = dict(os.environ)
    env["PYTHONPATH"] = _REPO + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    # Few threads per child: several plans must not starve the streaming thread.
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


class _Server:
    """The daemon's end of :mod:`hostd.planserver`: ``start(args)`` -> a :class:`_Forked`
    plan, or None where the server cannot be had (the caller runs the plan itself)."""

    def __init__(self):
        self.proc = None
        self.ready = False            # the server has its libraries loaded
        self.exits = {}               # pid -> exit code, from the server's reports
        self.replies = []
        self.cond = threading.Condition()

    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    def warm_up(self):
        """Start the server where none runs, without waiting for it."""
        with self.cond:
            if not self.alive():
                self._launch()

    def start(self, args):
        # Loading the libraries takes the server a second or more (several on a small
        # host): a plan asked for meanwhile runs on its own rather than hold up the
        # daemon's loop until the server is ready.
        with self.cond:
            if not self.alive():
                self._launch()
            if not self.ready:
                return None
            stderr = tempfile.NamedTemporaryFile(prefix="hostd-plan-", suffix=".stderr",
                                                 delete=False)
            stderr.close()
            try:
                # The daemon's environment now (a profile folder named there), not the
                # one the server started with.
                self.proc.stdin.write(json.dumps({"args": args, "stderr": stderr.name,
                                                  "env": _child_env()}) + "\n")
                self.proc.stdin.flush()
            except OSError:
                os.unlink(stderr.name)
                return None
            # The server answers as soon as it forked.
            if not self.cond.wait_for(lambda: self.replies or not self.alive(), timeout=10):
                self.proc.kill()
            if not self.replies:
                os.unlink(stderr.name)
                return None
            return _Forked(self, self.replies.pop(0), self.proc, stderr.name)

    def _launch(self):
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "hostd.planserver", str(os.getpid())],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                env=_child_env(), start_new_session=True, text=True, bufsize=1)
        except OSError:
            self.proc = None
            return
        self.replies, self.ready = [], False
        threading.Thread(target=self._read, args=(self.proc,), daemon=True,
                         name="planserver").start()

    def _read(self, proc):
        for line in proc.stdout:
            try:
                msg = json.loads(line)
            except ValueError:
                continue
            with self.cond:
                if "exit" in msg:
                    self.exits[msg["exit"]] = msg["code"]
                elif "pid" in msg:
                    self.replies.append(msg["pid"])
                elif msg.get("ready") and proc is self.proc:
                    self.ready = True
                self.cond.notify_all()
        with self.cond:
            self.cond.notify_all()


class _Forked:
    """A plan the server forked, as much of ``subprocess.Popen`` as :class:`PlanProcess`
    uses: ``pid``, ``poll()``, ``wait()``, ``kill()``, ``stderr`` (read once it ended)."""

    def __init__(self, server, pid, server_proc, stderr_path):
        self.server, self.pid, self._server_proc = server, pid, server_proc
        self._stderr_path = stderr_path
        self.stderr = None

    returncode = None

    def poll(self):
        if self.returncode is not None:
            return self.returncode
        with self.server.cond:
            code = self.server.exits.pop(self.pid, None)
            if code is None and self._server_proc.poll() is not None:
                # The server died, and its plans with it: nothing will report this one.
                code = -9
            if code is None:
                return None
        self.returncode = code
        self._take_stderr()
        return code

    def wait(self, timeout=None):
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired("plan %d" % self.pid, timeout)
            with self.server.cond:
                self.server.cond.wait(0.05)
        return self.returncode

    def kill(self):
        if self.returncode is None:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

    def _take_stderr(self):
        import io
        try:
            with open(self._stderr_path, "rb") as f:
                self.stderr = io.BytesIO(f.read())
            os.unlink(self._stderr_path)
        except OSError:
            self.stderr = io.BytesIO(b"")


_SERVER = None
_SERVER_LOCK = threading.Lock()


def warm_up():
    """Start the planning server (Linux) in the background, so that plans to come find
    it ready; it ends with the thread that calls this. The daemon leaves it to its first
    plan (which runs on its own meanwhile): a daemon that plans nothing keeps no server."""
    if sys.platform.startswith("linux"):
        _server().warm_up()


def _server():
    global _SERVER
    with _SERVER_LOCK:
        if _SERVER is None:
            _SERVER = _Server()
        return _SERVER


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


# Address space a plan needs beyond its libraries before it plans anything at all.
START_MB = 64


def _room_to_plan(memory_mb):
    """Raise MemoryError where ``memory_mb`` leaves the plan less than :data:`START_MB`
    beyond what its loaded libraries already map: the first allocations would fail, and
    some fail inside numpy's indexing, which then crashes (SIGSEGV) instead of raising.
    Linux only (elsewhere the plan finds out as it runs)."""
    try:
        with open("/proc/self/status") as f:
            size_kb = next(int(line.split()[1]) for line in f if line.startswith("VmSize:"))
    except (OSError, StopIteration, ValueError):
        return
    if memory_mb and size_kb / 1024 + START_MB > int(memory_mb):
        raise MemoryError("%d MB of libraries" % (size_kb / 1024))


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
        _room_to_plan(args.get("memory_mb"))
        profile = load_profile(args["profile"])
        result = plan_result(planner.run(args["input"], profile, outdir,
                                         progress=_stage_writer(outdir), keep=args.get("keep")))
    except PipelineError as exc:
        result = dict(exc.to_dict(), ok=False)
    except MemoryError as exc:
        start = str(exc) if "libraries" in str(exc) else ""
        result = {"ok": False, "code": "plan.memory_limit",
                  "text": "planning ran out of memory (limit %s MB%s)" % (
                      args.get("memory_mb"), start and ", less than the %s it loads and "
                      "%d MB more to start" % (start, START_MB)),
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
