"""What a new operator meets at the terminal: one exit convention for unknown jobs, no
traceback into a closed pipe, nothing written for a missing input, and help that lists
every output."""

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hostd import jobs as J
from hostd.cli import main
from hostd.commands import jobs as cli
from hostd.planner import output_names

ROOT = Path(__file__).resolve().parents[1]


def test_an_unknown_job_is_the_same_error_for_every_job_command(tmp_path, monkeypatch, capsys):
    store = J.JobStore(tmp_path / "jobs.sqlite")
    monkeypatch.setattr(cli, "_open", lambda args, need_daemon: (None, store, 1234))
    rc_job = cli.cmd_job(argparse.Namespace(id="nonexistent", config=None, json=False))
    err_job = capsys.readouterr().err
    for action in cli.JOB_ACTIONS:
        rc = cli.cmd_action(argparse.Namespace(action=action, target="nonexistent", config=None))
        err = capsys.readouterr().err
        assert (rc, err) == (rc_job, err_job) and "error jobs.unknown" in err
    assert store.pending_requests() == []        # nothing was asked of the daemon


def test_an_unknown_job_is_the_same_error_whether_or_not_a_daemon_runs(
        tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)                   # a stopped daemon's store in this folder
    J.JobStore(Path("hostd-data/state/jobs.sqlite")).close()
    assert main(["job", "nonexistent"]) == 2
    err_job = capsys.readouterr().err
    assert "error jobs.unknown" in err_job
    for action in cli.JOB_ACTIONS:
        assert (main([action, "nonexistent"]), capsys.readouterr().err) == (2, err_job)


def test_an_unknown_printer_is_refused_before_asking_the_daemon(tmp_path, monkeypatch, capsys):
    store = J.JobStore(tmp_path / "jobs.sqlite")
    store.set_printer("sim")
    monkeypatch.setattr(cli, "_open", lambda args, need_daemon: (None, store, 1234))
    monkeypatch.setattr(cli, "WAIT_S", 0.05)      # no daemon answers here
    for action in ("pause", "resume"):
        rc = cli.cmd_action(argparse.Namespace(action=action, target="nope", config=None))
        err = capsys.readouterr().err
        assert rc == 2 and "error control.unknown_printer" in err and "sim" in err, err
    assert store.pending_requests() == []


@pytest.mark.parametrize("where", ["missing.png", "a-folder"])
def test_a_missing_input_writes_nothing(where, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    if where == "a-folder":
        (tmp_path / where).mkdir()
    assert main(["plan", where, "-q"]) == 2
    err = capsys.readouterr().err
    assert "heightfield.not_found" in err
    assert ("a folder, not a file" if where == "a-folder" else "file not found") in err
    assert [p.name for p in tmp_path.iterdir()] == ([where] if where == "a-folder" else [])


def test_plan_help_lists_every_output(capsys):
    try:
        main(["plan", "--help"])
    except SystemExit:
        pass
    text = " ".join(capsys.readouterr().out.split())
    for name in output_names("NAME", color=True).values():
        assert name in text, name


def test_help_starts_without_loading_the_pipeline():
    # `hostd --help` and every command's help are asked often (and by the shell's
    # completion): the parser lists the outputs without importing the planner.
    code = ("import sys; from hostd.cli import build_parser; build_parser(); "
            "print(sorted(m for m in ('pipeline.plan', 'hostd.planner', 'scipy.sparse') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == "[]"


def test_a_closed_pipe_ends_the_listing_quietly(tmp_path):
    store = J.JobStore(tmp_path / "state" / "jobs.sqlite")
    for i in range(1500):                         # far more than a pipe buffers
        store.add("part-%04d.png" % i, "part-%04d.png" % i, tmp_path / "x.png", profile="p")
    store.close()
    (tmp_path / "hostd.yaml").write_text("state_dir: %s\ndrop_dir: %s\n" % (
        tmp_path / "state", tmp_path / "drop"))
    out = subprocess.run("%s -m hostd jobs -c %s | head -n 2" % (sys.executable,
                                                                  tmp_path / "hostd.yaml"),
                         shell=True, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert len(out.stdout.splitlines()) == 2
    assert "Traceback" not in out.stderr and "BrokenPipe" not in out.stderr, out.stderr


@pytest.mark.parametrize("command", ["jobs", "job", "--help"])
def test_a_closed_pipe_ends_quietly_when_the_output_waits_in_a_buffer(command, tmp_path):
    """A short listing stays in Python's buffer until exit: the reader being gone shows
    only then, and still ends quietly with 141."""
    store = J.JobStore(tmp_path / "state" / "jobs.sqlite")
    job = store.add("part.png", "part.png", tmp_path / "part.png", profile="p")
    store.close()
    (tmp_path / "hostd.yaml").write_text("state_dir: %s\n" % (tmp_path / "state"))
    argv = {"jobs": ["jobs"], "job": ["job", job], "--help": ["--help"]}[command]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    env["PYTHONPATH"] = str(ROOT)
    read, write = os.pipe()
    os.close(read)                                # the reader is gone before the first byte
    try:
        r = subprocess.run([sys.executable, "-m", "hostd"] + argv, cwd=tmp_path, env=env,
                           stdout=write, stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(write)
    assert r.returncode == 141, r.stderr
    assert "BrokenPipe" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr


def test_waitress_queue_depth_warnings_stay_out_of_the_log():
    import logging

    from hostd import logs
    logs.setup(stream=open("/dev/null", "w"))
    assert not logging.getLogger("waitress.queue").isEnabledFor(logging.WARNING)
    assert logging.getLogger("waitress.queue").isEnabledFor(logging.ERROR)


def test_a_fault_of_the_mesher_is_not_called_invalid_input(tmp_path, monkeypatch, capsys):
    from pipeline.errors import MeshingError
    from hostd import planner

    def broken(*args, **kw):
        raise MeshingError("2 edges shared by more than two triangles", code="mesh.overlap")
    monkeypatch.setattr(planner, "run", broken)
    (tmp_path / "x.npy").write_bytes(b"\x93NUMPY")
    assert main(["plan", str(tmp_path / "x.npy"), "-q", "-o", str(tmp_path)]) == 5
    err = capsys.readouterr().err
    assert "mesh.overlap" in err and "fault of hostd" in err and "--method free" in err
