"""``hostd sim-printer``: a simulated Marlin printer on a pseudo-terminal.

Prints the pty path on stdout (one line) and serves until killed; any host can open it
like a serial port. ``--link PATH`` also publishes it as a symlink (kept pointing at the
current pty across simulated disconnects). Options are those of ``sim://`` URLs.
"""

import json
import signal
import sys
import threading

from hostd.printer import PrinterError
from hostd.printer.sim import Simulator
from hostd.printer.simconfig import SimConfig


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "sim-printer", help="run a simulated Marlin printer on a pseudo-terminal",
        description=__doc__.split("\n\n")[0] + " See hostd/printer/simconfig.py for the options.")
    parser.add_argument("--baud", type=int, default=115200,
                        help="byte rate of the simulated wire, baud/10 bytes/s (default 115200)")
    parser.add_argument("--link", metavar="PATH", help="also publish the pty as symlink PATH")
    parser.add_argument("--record", metavar="FILE",
                        help="on exit, write the executed commands and statistics as JSON to FILE")
    SimConfig.add_arguments(parser)
    parser.set_defaults(func=run)
    return parser


def run(args):
    try:
        config = SimConfig.from_args(args)
    except PrinterError as exc:
        print("hostd sim-printer: %s" % exc, file=sys.stderr)
        return 2
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    sim = Simulator(config, baud=args.baud, link_path=args.link)
    try:
        sim.start()
    except PrinterError as exc:
        print("hostd sim-printer: %s" % exc, file=sys.stderr)
        return 1
    print(sim.endpoint.path, flush=True)   # the pty itself; --link points at it
    try:
        while not stop.wait(0.5):
            if sim.error is not None:
                print("hostd sim-printer: simulator failed: %r" % sim.error, file=sys.stderr)
                return 1
    finally:
        sim.stop()
        if args.record:
            with open(args.record, "w") as handle:
                json.dump(dict(commands=sim.commands(), stats=sim.stats), handle)
    return 0
