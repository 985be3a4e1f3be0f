"""The planning server: plans forked from one process that has the pipeline loaded."""

import os
import signal
import sys
import time

import pytest

from hostd import planning
from hostd.planning import PlanProcess

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="the server forks plans on Linux only")


def _parent(pid):
    with open("/proc/%d/stat" % pid) as f:
        return int(f.read().rsplit(")", 1)[1].split()[1])


def _ready_server(timeout=60):
    """The planning server, started and with its libraries loaded: its pid."""
    planning.warm_up()
    server = planning._server()
    deadline = time.monotonic() + timeout
    while not (server.ready and server.alive()):
        assert time.monotonic() < deadline, "the planning server did not get ready"
        time.sleep(0.02)
    return server.proc.pid


def _done(proc, timeout=120):
    deadline = time.monotonic() + timeout
    while (result := proc.poll()) is None:
        assert time.monotonic() < deadline, "the plan did not end"
        time.sleep(0.02)
    return result


def test_plans_are_forked_by_one_server_that_has_the_pipeline_loaded(tmp_path):
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=15, height_mm=3)
    _ready_server()
    first = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "a", 120, 4096)
    server = _parent(first.pid)
    assert server != os.getpid()
    with open("/proc/%d/cmdline" % server, "rb") as f:
        assert b"hostd.planserver" in f.read()
    second = PlanProcess("j2", src, "generic-0.5mm", tmp_path / "b", 120, 4096)
    assert _parent(second.pid) == server
    assert _done(first) == {"ok": True} and _done(second) == {"ok": True}
    assert (tmp_path / "a" / "dome.gcode").exists() and (tmp_path / "b" / "dome.gcode").exists()


def test_a_plan_whose_server_died_fails_and_the_next_plan_gets_a_new_server(tmp_path):
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=120, height_mm=20)   # ~10 s
    _ready_server()
    running = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "a", 120, 4096)
    server = _parent(running.pid)
    os.kill(server, signal.SIGKILL)
    result = _done(running, timeout=20)
    assert result["code"] == "plan.crashed" and "signal 9" in result["text"], result
    small = write_dome(tmp_path / "small.npy", diameter_mm=15, height_mm=3)
    _ready_server()
    after = PlanProcess("j2", small, "generic-0.5mm", tmp_path / "b", 120, 4096)
    assert _parent(after.pid) not in (server, os.getpid())
    assert _done(after) == {"ok": True}


def test_a_plan_that_crashes_says_its_last_error_line(tmp_path):
    """The child's stderr reaches the verdict as it did from a plan run on its own: a
    file where the node keeps its plans is no error the pipeline knows."""
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=15, height_mm=3)
    (tmp_path / "kept").write_text("a file, not a folder")
    proc = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "out", 120, 4096,
                       keep=tmp_path / "kept")
    result = _done(proc)
    assert result["code"] == "plan.crashed" and "status 1: " in result["text"], result
    assert "NotADirectoryError" in result["text"] or "FileExistsError" in result["text"]


def test_without_a_server_the_plan_runs_as_a_command_of_its_own(tmp_path, monkeypatch):
    from daemon_helpers import write_dome
    monkeypatch.setattr(planning._Server, "_launch", lambda self: False)
    monkeypatch.setattr(planning, "_SERVER", None)
    src = write_dome(tmp_path / "dome.npy", diameter_mm=15, height_mm=3)
    proc = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "a", 120, 4096)
    assert proc.proc.args[1:3] == ["-m", "hostd.planning"]
    assert _done(proc) == {"ok": True}


def test_a_limit_below_what_the_planner_loads_says_so(tmp_path):
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=15, height_mm=3)
    result = _done(PlanProcess("j1", src, "generic-0.5mm", tmp_path / "out", 120, 100))
    assert result["code"] == "plan.memory_limit", result
    assert "libraries" in result["text"] and "limit 100 MB" in result["text"]


def test_a_plan_that_outgrows_its_limit_while_planning_fails_as_out_of_memory(tmp_path):
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=120, height_mm=20)
    result = _done(PlanProcess("j1", src, "generic-0.5mm", tmp_path / "out", 120, 360))
    assert result["code"] == "plan.memory_limit", result
    assert "libraries" not in result["text"]


def test_a_plan_runs_in_the_daemons_environment_of_now_not_the_servers(tmp_path, monkeypatch):
    """A profile folder named after the server started is where the plan looks."""
    from pathlib import Path
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=15, height_mm=3)
    server = _ready_server()
    first = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "a", 120, 4096)
    assert _parent(first.pid) == server and _done(first)["ok"]
    generic = Path(__file__).resolve().parents[1] / "profiles" / "generic-0.5mm.yaml"
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "mine-0.5mm.yaml").write_text(
        generic.read_text().replace("name: generic-0.5mm", "name: mine-0.5mm"))
    monkeypatch.setenv("HOSTD_PROFILES", str(tmp_path / "profiles"))
    second = PlanProcess("j2", src, "mine-0.5mm", tmp_path / "b", 120, 4096)
    assert _parent(second.pid) == server and _done(second) == {"ok": True}


def test_a_plan_asked_for_while_the_server_loads_runs_on_its_own_at_once(tmp_path,
                                                                        monkeypatch):
    """The daemon's loop never waits for the server to load its libraries."""
    from daemon_helpers import write_dome
    monkeypatch.setattr(planning, "_SERVER", None)
    src = write_dome(tmp_path / "dome.npy", diameter_mm=15, height_mm=3)
    proc = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "a", 120, 4096)
    assert proc.proc.args[1:3] == ["-m", "hostd.planning"]
    assert planning._server().alive() and not planning._server().ready
    assert _done(proc) == {"ok": True}
    _ready_server()
    later = PlanProcess("j2", src, "generic-0.5mm", tmp_path / "b", 120, 4096)
    assert _parent(later.pid) == planning._server().proc.pid and _done(later) == {"ok": True}
