"""Where the running daemon is: a small file a started daemon writes so that terminal
commands (``hostd jobs``, ``hostd cancel`` ...) find its job store from any folder.

``$XDG_RUNTIME_DIR/hostd/daemon.json`` (else ``~/.cache/hostd/daemon.json``) holds the
configuration file and the folder it was started from; the daemon's own lock says whether
it still runs. With several daemons for one user, the file names the last one started.
"""

import json
import os
from pathlib import Path

from hostd.outputs import atomic_write, json_text


def runtime_file(environ=None):
    environ = os.environ if environ is None else environ
    base = environ.get("XDG_RUNTIME_DIR")
    return (Path(base) if base else Path.home() / ".cache") / "hostd" / "daemon.json"


def publish(config, started_in):
    """Say where this daemon's configuration is (best effort: a command can be given -c)."""
    path = runtime_file()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, json_text({"config": config.source if not _embedded(config) else None,
                                      "started_in": str(started_in), "pid": os.getpid(),
                                      "state_dir": str(config.state_dir)}))
    except OSError:
        pass


def withdraw():
    """Forget this daemon, if the file still names it."""
    path = runtime_file()
    try:
        if json.loads(path.read_text()).get("pid") == os.getpid():
            path.unlink()
    except (OSError, ValueError):
        pass


def running_config():
    """The configuration of the daemon the runtime file names, if it still runs; else None."""
    from hostd.config import DEFAULT_PATH, default_data, load_config, parse_config
    from hostd.lock import running_pid
    try:
        info = json.loads(runtime_file().read_text())
        if info.get("config"):
            config = load_config(info["config"])
        else:
            config = parse_config({}, DEFAULT_PATH, Path(info["started_in"]), default_data())
    except Exception:            # gone, damaged or moved: as if none ran
        return None
    return config if running_pid(config.lock_path) else None


def _embedded(config):
    from hostd.config import DEFAULT_PATH
    return config.source in (None, str(DEFAULT_PATH))
