"""``hostd token [--config FILE]``: create this node's web token, so the page's actions work.

Writes a new random token into the configuration's ``web.token``: into FILE, or into
``./hostd.yaml`` (created when missing; the embedded default fills in everything else).
The daemon reads it when it starts: start it (again) with ``hostd run -c FILE``.
"""

import secrets
import sys
from pathlib import Path

import yaml

DEFAULT_FILE = "hostd.yaml"


def add_parser(sub):
    p = sub.add_parser("token", help="create the web token that turns on the page's actions",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--config", "-c", default=DEFAULT_FILE, metavar="FILE",
                   help="the hostd.yaml to write it into (default: ./hostd.yaml)")
    p.set_defaults(func=run)


def run(args):
    path = Path(args.config)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) if path.exists() else None
    except (OSError, yaml.YAMLError) as exc:
        print("hostd token: error config.yaml: %s: %s. Fix: repair the file, or give another "
              "with --config" % (path, exc), file=sys.stderr)
        return 2
    data = data if isinstance(data, dict) else {}
    web = data.get("web") if isinstance(data.get("web"), dict) else {}
    token = secrets.token_urlsafe(24)
    web["token"] = token
    data["web"] = web
    existed = path.exists()
    part = path.with_name(path.name + ".part")
    part.write_text(("" if existed else "# hostd configuration: keys not given here take the "
                     "embedded default (docs/hostd.example.yaml)\n")
                    + yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    part.chmod(0o600)          # the token lets whoever reads it stop prints
    part.replace(path)
    print(token)
    print("hostd token: written to %s%s; start the daemon with `hostd run -c %s` (again, if it "
          "runs), then paste the token into the page's Token field"
          % (path, " (its comments were not kept)" if existed else "", path), file=sys.stderr)
    return 0
