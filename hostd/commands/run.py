"""``hostd run [--config FILE]``: the daemon (drop folder -> plan -> print), until SIGTERM."""

import sys

from hostd.errors import HostdError


def add_parser(sub):
    p = sub.add_parser("run", help="run the daemon: watch the drop folder, plan and print",
                       description="Watch the drop folder, plan every complete file in worker "
                                   "processes and print it on the configured printers. Without "
                                   "--config, an embedded default is used: folders under "
                                   "./hostd-data/ and one simulated printer.")
    p.add_argument("--config", "-c", default=None, metavar="FILE", help="hostd.yaml")
    p.add_argument("--node-id", default=None, help="override node_id from the config")
    p.add_argument("--check", action="store_true", help="validate the config, print it, exit")
    p.add_argument("--verbose", "-v", action="store_true", help="debug logging")
    p.set_defaults(func=run)


def run(args):
    import logging

    from hostd import daemon, logs
    from hostd.config import check_profiles, load_config
    logs.setup(logging.DEBUG if args.verbose else logging.INFO)
    try:
        overrides = {"node_id": args.node_id} if args.node_id else {}
        config = load_config(args.config, **overrides)
        check_profiles(config)
        if args.check:
            print("config OK: %s" % (config.source or "embedded default"))
            for key in ("node_id", "drop_dir", "state_dir", "outbox_dir", "done_dir", "failed_dir"):
                print("  %-10s %s" % (key, getattr(config, key)))
            for p in config.printers:
                print("  printer    %s: %s (%s)" % (p.name, p.port, p.profile))
            return 0
        return daemon.run(config)
    except HostdError as exc:
        print("hostd run: error %s: %s" % (exc.code, exc.text()), file=sys.stderr)
        return 2
