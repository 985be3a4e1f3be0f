"""Terminal commands over the job store of a running daemon.

``hostd jobs [--state S]``, ``hostd job ID``, ``hostd requeue ID``, ``hostd cancel ID``,
``hostd pause PRINTER``, ``hostd resume PRINTER``, ``hostd clear PRINTER`` (its bed is clear: after
every print a printer waits for a person to say so). Actions go to the daemon through the
store's control table; without a running daemon they are refused (listing still works).

Exit status: 0 done; 1 the daemon refused or did not answer; 2 nothing was asked of the
daemon, and stderr says why with an error code (an unknown job or printer, no daemon found
or running, a full or damaged job database).
"""

import json
import sys
import time

from hostd import share
from hostd.errors import HostdError

WAIT_S = 15.0


def _common(p):
    p.add_argument("--config", "-c", default=None, metavar="FILE",
                   help="hostd.yaml of the daemon (default: ./hostd.yaml, else the daemon "
                        "started in this folder, else the running one)")


def add_parser(sub):
    p = sub.add_parser("jobs", help="list jobs of the daemon (table)")
    _common(p)
    p.add_argument("--state", choices=_states(), help="only jobs in this state")
    p.add_argument("--json", action="store_true", help="JSON instead of a table")
    p.set_defaults(func=cmd_jobs)
    p = sub.add_parser("job", help="one job: its events and report summary")
    _common(p)
    p.add_argument("id", help="job id (a unique prefix is enough)")
    p.set_defaults(func=cmd_job)
    for action, what, help_ in (("requeue", "id", "queue a finished job again"),
                                ("cancel", "id", "cancel a queued, planning or printing job"),
                                ("approve", "id", "print a plan outside its profile's "
                                                  "printable limits anyway"),
                                ("pause", "printer", "pause a printer (it takes no new jobs)"),
                                ("resume", "printer", "resume a paused printer"),
                                ("clear", "printer", "say the printer's bed is clear (it waits "
                                                     "for this after every print)")):
        p = sub.add_parser(action, help=help_)
        _common(p)
        p.add_argument("target", metavar=what.upper())
        p.set_defaults(func=cmd_action, action=action)


def _states():
    from hostd.jobs import STATES
    return STATES


def _open(args, need_daemon):
    """The daemon's configuration, job store and pid (None when it does not run), found as
    :func:`hostd.runtime.locate` says; ``need_daemon``: refuse when it does not run."""
    from hostd.lock import running_pid
    from hostd.jobs import JobStore
    from hostd.runtime import locate
    config = locate(args.config)
    pid = running_pid(config.lock_path)
    if need_daemon:
        _require_daemon(config, pid)
    return config, JobStore(config.db_path, create=False), pid


def _require_daemon(config, pid):
    from hostd.config import DEFAULT_PATH
    from hostd.runtime import elsewhere, runtime_file
    if pid:
        return
    own = config.source not in (None, str(DEFAULT_PATH))
    raise HostdError("no hostd daemon runs with state folder %s%s"
                     % (config.state_dir, elsewhere(config)), code="control.no_daemon",
                     fix="start it with `hostd run%s`, or point at its configuration with "
                         "--config (a running daemon says where it is in %s)"
                         % (" --config " + config.source if own else "", runtime_file()))


def _fail(exc):
    print("hostd: error %s: %s" % (exc.code, exc.text()), file=sys.stderr)
    return 2


def _when(t):
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t)) if t else "-"


def cmd_jobs(args):
    try:
        config, store, pid = _open(args, need_daemon=False)
    except HostdError as exc:
        return _fail(exc)
    rows = store.list(args.state)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    if not pid:
        from hostd.runtime import elsewhere
        print("(no daemon runs with %s: showing its stored jobs%s)"
              % (config.state_dir, elsewhere(config)), file=sys.stderr)
    print("%-22s %-11s %-10s %5s %-3s %-19s %s" % ("ID", "STATE", "PRINTER", "PROG", "PRI",
                                                  "CREATED", "NAME"))
    for r in rows:
        print("%-22s %-11s %-10s %4.0f%% %3d %-19s %s%s" % (
            r["id"], r["state"], r["printer"] or "-", 100 * (r["progress"] or 0), r["priority"],
            _when(r["created_at"]), r["rel_path"], _doing(r)))
    return 0


def _doing(job):
    """What a job waits on or is doing, after its name: the plan's stage, or a decision."""
    if job["state"] == "planning" and job.get("stage"):
        return "  (planning: %s)" % job["stage"]
    if job.get("decision"):
        return "  (waits for `hostd approve %s`)" % job["id"]
    return ""


def cmd_job(args):
    from pathlib import Path
    try:
        _, store, _ = _open(args, need_daemon=False)
        job = store.require(args.id)
    except HostdError as exc:
        return _fail(exc)
    for key in ("id", "name", "rel_path", "state", "stage", "decision", "printer", "profile",
                "priority", "copies", "progress", "last_line", "input_path", "outbox", "error"):
        if key == "stage" and job["state"] != "planning":
            continue
        value = job[key]
        if key == "progress":
            value = "%.1f %%" % (100 * (value or 0))
        print("%-11s %s" % (key + ":", value if value is not None else "-"))
    print("events:")
    for e in store.events(job["id"]):
        print("  %s  %-11s %s" % (_when(e["at"]), e["kind"], e["message"] or ""))
    reports = sorted(Path(job["outbox"]).glob("*.report.json")) if job["outbox"] else []
    if reports:
        try:
            r = share.read_json(reports[0], share.REPORT_BYTES)
            print("report: %s" % reports[0])
            for section, keys in (("mesh", ("triangles",)),
                                  ("simulation", ("mean_displacement_mm", "max_displacement_mm")),
                                  ("gcode", ("lines", "estimated_print_s", "filament_mm"))):
                for k in keys:
                    if k in r.get(section, {}):
                        print("  %s.%s: %s" % (section, k, r[section][k]))
        except (OSError, ValueError, HostdError):
            pass
    return 0


JOB_ACTIONS = ("requeue", "cancel", "approve")


def cmd_action(args):
    try:
        config, store, pid = _open(args, need_daemon=False)
        # An unknown job or printer is an error of the command line, told as `hostd job`
        # tells it (whether or not a daemon runs), and nothing is asked of the daemon.
        if args.action in JOB_ACTIONS:
            args.target = store.require(args.target)["id"]
        else:
            _require_printer(store, args.target)
        _require_daemon(config, pid)
        req = store.request(args.action, args.target)   # e.g. jobs.disk_full
    except HostdError as exc:
        return _fail(exc)
    answer = store.wait_answer(req, timeout_s=WAIT_S)
    if answer is None:
        print("hostd: the daemon did not answer within %.0f s" % WAIT_S, file=sys.stderr)
        return 1
    ok, text = answer
    print(text if ok else "hostd: %s" % text, file=sys.stdout if ok else sys.stderr)
    return 0 if ok else 1


def _require_printer(store, name):
    known = store.printers()
    if known and name not in known:     # none yet: a daemon starting, let it answer
        raise HostdError("no printer %r" % name, code="control.unknown_printer",
                         fix="printers here: " + ", ".join(sorted(known)))
