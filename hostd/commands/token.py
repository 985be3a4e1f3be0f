"""``hostd token [--config FILE]``: create this node's web token, so the page's actions work.

Writes a new random token into the configuration's ``web.token``: into FILE, or into
``./hostd.yaml`` (created when missing; the embedded default fills in everything else).
The daemon reads it when it starts: start it (again) with ``hostd run -c FILE``.
"""

import os
import secrets
import stat
import sys
from pathlib import Path

import yaml

DEFAULT_FILE = "hostd.yaml"
HEADER = ("# hostd configuration: keys not given here take the embedded default "
          "(docs/hostd.example.yaml)\n")


def add_parser(sub):
    p = sub.add_parser("token", help="create the web token that turns on the page's actions",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--config", "-c", default=DEFAULT_FILE, metavar="FILE",
                   help="the hostd.yaml to write it into (default: ./hostd.yaml)")
    p.set_defaults(func=run)


def run(args):
    path = Path(args.config)
    # A symlinked hostd.yaml stays a link: the new text goes to the file it points at.
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    try:
        data = yaml.safe_load(target.read_text(encoding="utf-8")) if target.exists() else None
    except (OSError, yaml.YAMLError) as exc:
        print("hostd token: error config.yaml: %s: %s. Fix: repair the file, or give another "
              "with --config" % (path, exc), file=sys.stderr)
        return 2
    data = data if isinstance(data, dict) else {}
    web = data.get("web") if isinstance(data.get("web"), dict) else {}
    token = secrets.token_urlsafe(24)
    web["token"] = token
    data["web"] = web
    existed = target.exists()
    text = ("" if existed else HEADER) + yaml.safe_dump(data, sort_keys=False)
    try:
        write_private(target, text)
    except OSError as exc:
        print("hostd token: error config.write: cannot write %s: %s. Fix: check the folder's "
              "permissions, or give another file with --config" % (target, exc), file=sys.stderr)
        return 2
    print(token)
    print("hostd token: written to %s%s; start the daemon with `hostd run -c %s` (again, if it "
          "runs), then paste the token into the page's Token field"
          % (path, " (its comments were not kept)" if existed else "", path), file=sys.stderr)
    return 0


def write_private(target, text):
    """Replace ``target`` atomically with ``text``, readable by no one else at any moment.

    The new file is made beside it with O_EXCL|O_NOFOLLOW and mode 0600 (a planted
    ``.part`` symlink is never followed). An existing file keeps its owner, group and
    group bits (``sudo hostd token`` must leave the service able to read it); world bits
    are dropped, since the token lets whoever reads it stop prints.
    """
    old = None
    try:
        old = os.stat(target)
    except FileNotFoundError:
        pass
    part = target.with_name(target.name + ".part")
    fd = _create(part)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            if old is not None:
                _keep_owner(f.fileno(), old)
            os.fsync(f.fileno())
        os.replace(part, target)
    except BaseException:
        try:
            os.unlink(part)
        except OSError:
            pass
        raise


def _create(part):
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
    try:
        return os.open(part, flags, 0o600)
    except FileExistsError:
        # Left by an interrupted run, or planted: unlink removes the name (a symlink's
        # target is untouched), and O_EXCL makes the retry create a file of our own.
        os.unlink(part)
        return os.open(part, flags, 0o600)


def _keep_owner(fd, old):
    if (old.st_uid, old.st_gid) != (os.geteuid(), os.getegid()):
        try:
            os.fchown(fd, old.st_uid, old.st_gid)
        except PermissionError:
            if old.st_gid != os.getegid():
                try:
                    os.fchown(fd, -1, old.st_gid)
                except PermissionError:
                    pass
    os.fchmod(fd, stat.S_IMODE(old.st_mode) & 0o660 | 0o600)
