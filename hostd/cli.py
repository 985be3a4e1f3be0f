"""Command-line entry point: ``hostd <command> ...``.

Each subcommand lives in ``hostd.commands.<name>`` and registers itself through
``add_parser``; a module that is missing or fails to import is reported, not hidden.
"""

import argparse
import importlib
import os
import sqlite3
import sys

from pipeline import __version__

# Order is the order shown in --help.
COMMANDS = ["run", "plan", "stream", "sim_printer", "calibrate", "jobs", "token", "keys"]


def build_parser():
    parser = argparse.ArgumentParser(
        prog="hostd", description="Printer-host service for 4D printing of height fields.")
    parser.add_argument("--version", action="version", version="hostd " + __version__)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module("hostd.commands." + name)
        except ModuleNotFoundError as exc:
            if exc.name == "hostd.commands." + name:
                continue  # command not built yet
            raise
        module.add_parser(sub)
    return parser


def main(argv=None):
    try:
        try:
            return _run(argv)
        finally:
            # Output to a pipe waits in a buffer: flush it here, so that a reader gone away
            # shows below and not as Python's "Exception ignored ... BrokenPipeError" at exit
            # (which also happens on --help, where argparse exits by SystemExit).
            sys.stdout.flush()
    except BrokenPipeError:
        # The reader went away (`hostd jobs | head`): stop quietly with 141, the status a
        # shell reports for cat or ls ended by SIGPIPE (128 + 13), so `set -o pipefail`
        # scripts see hostd as they see those; stdout goes to devnull so that Python's
        # own flush at exit finds no pipe to complain about.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


def _run(argv):
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("hostd: interrupted", file=sys.stderr)
        return 130
    except sqlite3.DatabaseError as exc:
        from hostd.jobs import DAMAGED, is_damage
        if not is_damage(exc):
            raise
        print("hostd: error %s: the job database is damaged (SQLite: %s). Fix: restart the "
              "daemon (`systemctl restart hostd`): it keeps the damaged file aside, starts a "
              "new one and queues this node's claimed files again" % (DAMAGED, exc),
              file=sys.stderr)
        return 2
