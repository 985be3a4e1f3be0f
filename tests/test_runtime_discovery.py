"""Terminal commands find the running daemon's job store from any folder: the daemon says
where it is in a runtime file while it runs, and withdraws it when it stops."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from daemon_helpers import DaemonProcess, write_config, write_dome

ROOT = Path(__file__).resolve().parents[1]


def test_hostd_jobs_finds_the_running_daemon_from_another_folder(tmp_path):
    run_dir = tmp_path / "run"
    env = {"XDG_RUNTIME_DIR": str(run_dir)}
    config = write_config(tmp_path, web={"host": "127.0.0.1", "port": 0, "token": None})
    write_dome(tmp_path / "share" / "drop" / "dome.npy")
    d = DaemonProcess(config, env=env)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    pointer = run_dir / "hostd" / "daemon.json"
    try:
        deadline = time.monotonic() + 60
        while not pointer.exists():
            assert time.monotonic() < deadline, d.output()[-2000:]
            time.sleep(0.2)
        assert json.loads(pointer.read_text())["config"] == str(config)
        out = ""
        while "dome.npy" not in out:
            assert time.monotonic() < deadline, out
            r = subprocess.run([sys.executable, "-m", "hostd", "jobs"], cwd=elsewhere,
                               env=dict(os.environ, PYTHONPATH=str(ROOT), **env),
                               capture_output=True, text=True, timeout=30)
            out = r.stdout
            time.sleep(0.2)
        assert r.returncode == 0 and "no daemon runs" not in r.stderr
    finally:
        assert d.stop() == 0, d.output()[-2000:]
    assert not pointer.exists()
