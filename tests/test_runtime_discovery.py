"""Terminal commands find the running daemon's job store from any folder: the daemon says
where it is in a runtime file while it runs, and withdraws it when it stops."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

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


# -- which daemon a terminal command is about, without starting one ----------------------------

@pytest.fixture
def pointer(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "run"))
    return tmp_path / "run" / "hostd" / "daemon.json"


@pytest.fixture
def traces(pointer, monkeypatch):
    """traces(folder, job, running, config): what a daemon leaves in ``folder`` (its
    ``hostd.yaml``, a store holding ``job``) and, when ``running``, its lock held and the
    runtime file naming it, as `hostd run -c CONFIG` started in ``folder`` does; returns
    its config."""
    from hostd import jobs as J
    from hostd import runtime
    from hostd.config import load_config
    from hostd.lock import DaemonLock
    locks = []

    def make(folder, job, running, config="hostd.yaml"):
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "hostd.yaml").write_text("poll_s: 2.0\n")
        monkeypatch.chdir(folder)
        config = load_config(config)
        J.JobStore(config.db_path).add(job, job, folder / job, profile="p")
        if running:
            locks.append(DaemonLock(config.lock_path))
            locks[-1].acquire()
            runtime.publish(config, folder)
        return config
    yield make
    for lock in locks:
        lock.release()


def listed(capsys):
    from hostd.cli import main
    assert main(["jobs", "--json"]) == 0
    return [j["name"] for j in json.loads(capsys.readouterr().out)]


def test_a_daemon_started_with_a_relative_config_is_found_from_another_folder(
        tmp_path, monkeypatch, traces, capsys):
    traces(tmp_path / "started", "there.png", running=True)
    monkeypatch.chdir(tmp_path)
    assert listed(capsys) == ["there.png"]


@pytest.mark.parametrize("here", ["hostd.yaml", "hostd-data"])
def test_this_folders_daemon_comes_before_the_one_running_elsewhere(
        here, tmp_path, monkeypatch, traces, capsys):
    from hostd import jobs as J
    from hostd.cli import main
    from hostd.config import load_config
    traces(tmp_path / "elsewhere", "there.png", running=True,
           config=tmp_path / "elsewhere" / "hostd.yaml")
    folder = tmp_path / "here"
    if here == "hostd.yaml":
        traces(folder, "here.png", running=False)
    else:                                           # `hostd run` with the embedded default
        folder.mkdir()
        monkeypatch.chdir(folder)
        J.JobStore(load_config().db_path).add("here.png", "here.png", folder, profile="p")
    assert listed(capsys) == ["here.png"]
    assert main(["jobs"]) == 0
    assert "a daemon runs with --config %s" % (tmp_path / "elsewhere" / "hostd.yaml") in \
        capsys.readouterr().err


def test_an_action_on_this_folders_stopped_daemon_names_the_running_one(
        tmp_path, traces, capsys):
    from hostd.cli import main
    from hostd.jobs import JobStore
    other = traces(tmp_path / "elsewhere", "there.png", running=True)
    here = traces(tmp_path / "here", "here.png", running=False)
    job = JobStore(here.db_path).list()[0]["id"]
    assert main(["cancel", job]) == 2
    err = capsys.readouterr().err
    assert "error control.no_daemon" in err
    assert "a daemon runs with --config %s" % (tmp_path / "elsewhere" / other.source) in err


def test_when_no_daemon_is_found_the_command_says_where_it_looked(
        tmp_path, monkeypatch, pointer, capsys):
    from hostd.cli import main
    monkeypatch.chdir(tmp_path)
    for argv in (["jobs"], ["job", "x"], ["cancel", "x"], ["pause", "sim"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "error control.not_found" in err and "--config FILE" in err, err
        for place in ("./hostd.yaml", str(tmp_path / "hostd-data" / "state" / "jobs.sqlite"),
                      str(pointer)):
            assert place in err, (place, err)
