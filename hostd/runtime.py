"""Where the running daemon is: a small file a started daemon writes so that terminal
commands (``hostd jobs``, ``hostd cancel`` ...) find its job store from any folder.

``$XDG_RUNTIME_DIR/hostd/daemon.json`` (else ``~/.cache/hostd/daemon.json``) holds the
configuration file and the folder it was started from; the daemon's own lock says whether
it still runs. With several daemons for one user, the file names the last one started.
"""

import os
from pathlib import Path

from hostd.errors import HostdError
from hostd.outputs import atomic_write, json_text

LOCAL_CONFIG = "hostd.yaml"    # what `hostd token` writes and `hostd run -c` reads


def runtime_file(environ=None):
    environ = os.environ if environ is None else environ
    base = environ.get("XDG_RUNTIME_DIR")
    return (Path(base) if base else Path.home() / ".cache") / "hostd" / "daemon.json"


def publish(config, started_in):
    """Say where this daemon's configuration is (best effort: a command can be given -c)."""
    path = runtime_file()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # A relative --config is read from the folder the daemon was started in.
        source = None if _embedded(config) else os.path.join(started_in, config.source)
        atomic_write(path, json_text({"config": source, "started_in": str(started_in),
                                      "pid": os.getpid(), "state_dir": str(config.state_dir)}))
    except OSError:
        pass


def withdraw():
    """Forget this daemon, if the file still names it."""
    path = runtime_file()
    try:
        if _read(path).get("pid") == os.getpid():
            path.unlink()
    except (OSError, ValueError, HostdError, AttributeError):
        pass


def _read(path):
    """The runtime file's JSON: a regular file of a few hundred bytes (a FIFO or a link to
    /dev/zero put in its place would hang every terminal command)."""
    from hostd import share
    return share.read_json(path)


def running_config():
    """The configuration of the daemon the runtime file names, if it still runs; else None."""
    return _running()[0]


def _running():
    """(config, the folder it was started in) of the daemon the runtime file names, if it
    still runs; else (None, None)."""
    from hostd.config import DEFAULT_PATH, default_data, load_config, parse_config
    from hostd.lock import running_pid
    try:
        info = _read(runtime_file())
        if info.get("config"):
            config = load_config(info["config"])
        else:
            config = parse_config({}, DEFAULT_PATH, Path(info["started_in"]), default_data())
    except Exception:            # gone, damaged or moved: as if none ran
        return None, None
    return (config, info.get("started_in")) if running_pid(config.lock_path) else (None, None)


def locate(path=None):
    """The configuration a terminal command is about, first found of: the file ``path``
    (``--config``); ``./hostd.yaml``; the embedded default's, when its job store is in this
    folder (the daemon was started here); the running daemon's, from the runtime file.
    This folder comes before the runtime file, which names only the last daemon started."""
    from hostd.config import load_config
    if path:
        return load_config(path)
    if Path(LOCAL_CONFIG).is_file():
        return load_config(LOCAL_CONFIG)
    here = load_config()
    if here.db_path.exists():
        return here
    running = running_config()
    if running is not None:
        return running
    pointer = runtime_file()
    raise HostdError("no hostd daemon found from %s" % Path.cwd(), code="control.not_found",
                     fix="give its configuration with --config FILE (e.g. `-c "
                         "/etc/hostd/hostd.yaml`), or run the command in the folder it was "
                         "started in. Looked for ./%s, %s and %s (%s)" % (
                             LOCAL_CONFIG, here.db_path, pointer,
                             "it names no running daemon" if pointer.exists() else
                             "a running `hostd run` writes it"))


def elsewhere(config):
    """How to reach the daemon that runs, when it is not the one of ``config``: "" or a hint."""
    running, started_in = _running()
    if running is None or running.state_dir == config.state_dir:
        return ""
    if _embedded(running):
        return "; a daemon started in %s runs: run the command there" % started_in
    return "; a daemon runs with --config %s" % running.source


def _embedded(config):
    from hostd.config import DEFAULT_PATH
    return config.source in (None, str(DEFAULT_PATH))
