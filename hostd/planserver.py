"""A planning server: one process with the pipeline loaded that forks each plan.

A plan started as ``python -m hostd.planning`` first imports numpy, scipy, shapely and
the pipeline: 0.9-1.2 s of CPU on a server core, more on a slower host, for every plan.
The server imports them once and forks a child per plan, which runs
:func:`hostd.planning.child_main` as that command would (its own session, its limits,
killed with its parent); its stderr goes to a file the daemon reads.

The daemon talks to the server over its stdin and stdout, a JSON object per line. The
server says ``{"ready": true}`` once its libraries are loaded (plans asked for before
then run on their own). ``{"args": ..., "stderr": path, "env": {...}}`` starts a plan in
that environment (what the libraries read as they load, such as the BLAS threads, is the
server's) and is answered ``{"pid": n}``; every plan that ends is reported
``{"exit": pid, "code": c}`` (``c`` < 0: killed by signal ``-c``). The server dies with
the daemon thread that started it (Linux), and ends at the end of its stdin; either way
its plans die with it.
"""

import json
import os
import select
import signal
import sys


def main(argv):
    from hostd import planning
    parent = int(argv[0]) if argv else 0
    planning._die_with_parent(parent)
    # The daemon reads only the server's reports: whatever a library prints goes nowhere.
    out = os.fdopen(os.dup(1), "w")
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.close(null)
    _preload()
    _send(out, {"ready": True})
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stdin = sys.stdin.fileno()
    pending = b""
    while True:
        ready, _, _ = select.select([stdin, wake_r], [], [])
        if wake_r in ready:
            os.read(wake_r, 512)
        _report_exits(out)
        if stdin in ready:
            chunk = os.read(stdin, 65536)
            if not chunk:
                return 0
            pending += chunk
            *lines, pending = pending.split(b"\n")
            for line in lines:
                if line.strip():
                    pid = _fork_plan(json.loads(line), (wake_r, wake_w, stdin, out.fileno()))
                    _send(out, {"pid": pid})


def _preload():
    """Import what plans import, once: :mod:`hostd.planner` and every module of the
    pipeline (many are imported inside the stage that needs them). A child then imports
    nothing under its address-space limit, and OpenBLAS is loaded before any limit."""
    import importlib
    import pkgutil

    import pipeline
    from hostd import planner  # noqa: F401
    for info in pkgutil.walk_packages(pipeline.__path__, "pipeline."):
        try:
            importlib.import_module(info.name)
        except Exception:   # a module a plan cannot import fails that plan, not the server
            pass


def _report_exits(out):
    """Reap every child that ended and tell the daemon its exit code."""
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        _send(out, {"exit": pid, "code": os.waitstatus_to_exitcode(status)})


def _send(out, obj):
    out.write(json.dumps(obj) + "\n")
    out.flush()


def _fork_plan(request, server_fds):
    """Fork a child that runs the plan ``request["args"]``: its pid."""
    args = dict(json.loads(request["args"]), parent_pid=os.getpid())
    pid = os.fork()
    if pid:
        return pid
    code = 1
    try:
        os.setsid()
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for fd in server_fds:
            os.close(fd)
        null = os.open(os.devnull, os.O_RDWR)
        err = os.open(request["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        os.dup2(null, 0)
        os.dup2(null, 1)
        os.dup2(err, 2)
        sys.stdin = open(os.devnull)
        sys.stdout = open(os.devnull, "w")
        sys.stderr = os.fdopen(2, "w", buffering=1)
        import faulthandler
        faulthandler.enable()     # a crash in C code leaves its Python stack in stderr
        os.environ.clear()
        os.environ.update(request["env"])
        from hostd import planning
        code = planning.child_main([json.dumps(args)])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:
        import traceback
        traceback.print_exc()
        code = 1
    finally:
        try:
            sys.stderr.flush()
        finally:
            os._exit(code)


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
