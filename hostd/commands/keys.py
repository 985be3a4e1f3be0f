"""``hostd keys list|approve|deny|revoke``: the application keys OctoPrint clients ask for.

An app (Home Assistant, a farm dashboard) asks the node for a key; the request waits here
and on the status page until a person approves or denies it. Deciding needs the web token:
the command works with a configuration that holds one (``hostd token`` writes it), read as
``hostd jobs`` reads its configuration. Keys are never shown: only their app and id.

Exit status: 0 done; 2 nothing done, and stderr says why with an error code.
"""

import json
import sys
import time

from hostd.errors import HostdError


def add_parser(sub):
    p = sub.add_parser("keys", help="list, approve, deny or revoke application keys",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--config", "-c", default=None, metavar="FILE",
                   help="hostd.yaml of the node (default: as `hostd jobs` finds it)")
    p.add_argument("action", choices=("list", "approve", "deny", "revoke"))
    p.add_argument("target", nargs="?", metavar="ID",
                   help="a request's id (approve, deny), or a key's id or app (revoke)")
    p.add_argument("--json", action="store_true", help="list as JSON")
    p.set_defaults(func=run)


def _when(t):
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t)) if t else "-"


def _store(args):
    from hostd.appkeys import KeyStore
    from hostd.runtime import locate
    from hostd.web.api import NO_TOKEN
    config = locate(args.config)
    if not config.web.token:
        raise HostdError("application keys are off on this node: " + NO_TOKEN,
                         code="appkeys.off", file=config.source)
    return KeyStore(config.state_dir)


def run(args):
    try:
        store = _store(args)
        if args.action == "list":
            return _list(store, args.json)
        if not args.target:
            raise HostdError("`hostd keys %s` needs an ID" % args.action, code="appkeys.usage",
                             fix="`hostd keys list` shows the ids")
        print(getattr(store, args.action)(args.target))
        return 0
    except HostdError as exc:
        print("hostd: error %s: %s" % (exc.code, exc.text()), file=sys.stderr)
        return 2


def _list(store, as_json):
    pending, keys = store.pending(), store.keys()
    if as_json:
        print(json.dumps({"pending": pending, "keys": keys}, indent=1))
        return 0
    print("pending requests:" if pending else "no pending requests")
    for r in pending:
        print("  %-8s %-19s %-15s %s%s" % (r["id"], _when(r["at"]), r["remote"] or "-",
                                           r["app"], " (%s)" % r["user"] if r["user"] else ""))
    print("keys:" if keys else "no keys")
    for k in keys:
        print("  %-8s approved %-19s last used %-19s %s" % (
            k["id"], _when(k["created"]), _when(k["last_used"]), k["app"]))
    return 0
