"""``hostd stream FILE.gcode --port URL [--baud N]``: stream a G-code file to a printer.

Like printcore: connect, send every line with checksums and flow control, show a
progress bar on a terminal, and end with one JSON line on stdout::

    {"lines": int, "bytes": int, "resends": int, "seconds": f, "lines_per_s": f,
     "link_utilisation": f, "result": "done"|"cancelled"|"error", "error": str|null}

``link_utilisation`` is bytes sent per second over the link's byte rate (baud/10).
Ctrl-C cancels (runs the cancel G-code; before printing starts it only disconnects,
with ``result: cancelled``); a second Ctrl-C is an emergency stop.
Exit status 0 only when the result is ``done``.
"""

import json
import sys

from hostd.printer import LinkSettings, Printer, PrinterError

BAR_WIDTH = 30


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "stream", help="stream a G-code file to a printer (serial, socket://, rfc2217://, sim://)",
        description=__doc__.split("\n\n")[0])
    parser.add_argument("file", metavar="FILE.gcode", help="G-code file to print")
    parser.add_argument("--port", required=True,
                        help="device path, pyserial URL (socket://host:port, rfc2217://) or sim://?options")
    parser.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200)")
    parser.add_argument("--ping-pong", action="store_true",
                        help="one line in flight even if the firmware reports ADVANCED_OK")
    parser.add_argument("--ok-timeout", type=float, default=LinkSettings.ok_timeout_s, metavar="S",
                        help="seconds of silence before the M105/resend recovery (default %(default)s)")
    parser.add_argument("--open-timeout", type=float, default=LinkSettings.open_timeout_s, metavar="S",
                        help="wait this long for the port to appear (default %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar even on a terminal")
    parser.set_defaults(func=run)
    return parser


def run(args):
    settings = LinkSettings(baud=args.baud, send_ahead=not args.ping_pong, ok_timeout_s=args.ok_timeout,
                            open_timeout_s=args.open_timeout, reconnect=False)
    show = sys.stderr.isatty() and not args.no_progress
    summary = dict(lines=0, bytes=0, resends=0, seconds=0.0, lines_per_s=0.0, link_utilisation=0.0,
                   result="error", error=None)
    printer = job = None
    try:
        if show:
            print("hostd stream: connecting to %s at %d baud" % (args.port, args.baud), file=sys.stderr)
        printer = Printer(args.port, settings)
        printer.connect()
        job = printer.start(args.file)
        snapshot = _follow(printer, job, show)
        summary.update(_summary(snapshot, args.baud))
    except PrinterError as exc:
        summary["error"] = str(exc)
        print("hostd stream: %s" % exc, file=sys.stderr)
    except KeyboardInterrupt:
        # _follow handles Ctrl-C once printing; a job just started is cancelled by close().
        when = "just after printing started" if job is not None else "before printing started"
        summary.update(result="cancelled", error="interrupted " + when)
        print("\nhostd stream: interrupted %s" % when, file=sys.stderr)
    finally:
        # The JSON line is the command's contract with scripts: it is written whatever
        # ends the stream, even an error nobody foresaw (then followed by its traceback).
        try:
            if printer is not None:
                printer.close()
        finally:
            print(json.dumps(summary), flush=True)
    return 0 if summary["result"] == "done" else 1


def _follow(printer, job, show):
    """Wait for the job, drawing the progress bar; Ctrl-C cancels, twice stops at once."""
    interrupts = 0
    while True:
        try:
            if job.wait(0.2):
                break
            if show:
                _draw(job.snapshot())
        except KeyboardInterrupt:
            interrupts += 1
            if interrupts == 1:
                print("\nhostd stream: cancelling (Ctrl-C again for emergency stop)", file=sys.stderr)
                try:
                    printer.cancel()
                except PrinterError:
                    pass
            else:
                print("\nhostd stream: emergency stop", file=sys.stderr)
                printer.estop()
    snapshot = job.snapshot()
    if show:
        _draw(snapshot)
        sys.stderr.write("\n")
    if snapshot["result"] != "done":
        print("hostd stream: %s: %s" % (snapshot["result"], snapshot["error"] or printer.last_error),
              file=sys.stderr)
    return snapshot


def _draw(snapshot):
    total = snapshot["total"] or 0
    done = snapshot["confirmed"]
    fraction = done / total if total else 0.0
    filled = int(fraction * BAR_WIDTH)
    rate = done / snapshot["seconds"] if snapshot["seconds"] > 0 else 0.0
    sys.stderr.write("\r[%s%s] %5.1f%% %d/%d lines %.0f lines/s %s " % (
        "#" * filled, " " * (BAR_WIDTH - filled), 100 * fraction, done, total, rate, snapshot["phase"]))
    sys.stderr.flush()


def _summary(snapshot, baud):
    seconds = snapshot["seconds"]
    result = snapshot["result"]
    error = snapshot["error"]
    if result not in ("done", "cancelled"):
        error = error or result
        result = "error"
    return dict(lines=snapshot["confirmed"], bytes=snapshot["bytes_sent"], resends=snapshot["resends"],
                seconds=round(seconds, 4),
                lines_per_s=round(snapshot["confirmed"] / seconds, 2) if seconds > 0 else 0.0,
                link_utilisation=round(snapshot["bytes_sent"] / seconds / (baud / 10.0), 4) if seconds > 0 else 0.0,
                result=result, error=error)
