"""systemd units: required hardening and notify settings; systemd-analyze verify if present."""

import configparser
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hostd.config import load_config
from hostd.planning import PlanProcess

SYSTEMD = Path(__file__).resolve().parents[1] / "systemd"
ROOT = SYSTEMD.parent


def _unit(name):
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read(SYSTEMD / name)
    return parser


@pytest.mark.parametrize("name", ["hostd.service", "hostd@.service"])
def test_unit_settings(name):
    s = _unit(name)["Service"]
    assert s["Type"] == "notify" and s["Restart"] == "on-failure"
    assert int(s["WatchdogSec"]) > 0 and s["User"] == "hostd"
    assert "dialout" in s["SupplementaryGroups"]
    for key in ("NoNewPrivileges", "ProtectHome", "PrivateTmp"):
        assert s[key] == "yes"
    assert s["ProtectSystem"] == "strict" and s["ReadWritePaths"]
    assert "hostd run --config" in s["ExecStart"]


def test_udev_rule_and_example_config(tmp_path):
    rule = (SYSTEMD / "99-hostd-printers.rules").read_text()
    assert 'SYMLINK+="printer/' in rule and 'TAG+="systemd"' in rule
    config = load_config(ROOT / "docs" / "hostd.example.yaml")
    assert config.printers[0].port == "/dev/printer/mk3-left"


@pytest.mark.skipif(not shutil.which("systemd-analyze"), reason="systemd-analyze not available")
@pytest.mark.parametrize("name", ["hostd.service", "hostd@.service"])
def test_systemd_analyze_verify(tmp_path, name):
    text = (SYSTEMD / name).read_text().replace("/opt/hostd/.venv/bin/hostd", sys.executable)
    target = tmp_path / (name.replace("@", "@test") if "@" in name else name)
    target.write_text(text)
    r = subprocess.run(["systemd-analyze", "verify", str(target)], capture_output=True,
                       text=True, timeout=60)
    problems = [line for line in (r.stdout + r.stderr).splitlines()
                if str(target.name) in line and "dev-printer" not in line
                and "Failed to" not in line]
    assert problems == [], problems


def test_plan_time_limit_stops_the_process(tmp_path):
    """A plan of a few seconds under a limit of a fraction of one (a plan forked by the
    planning server starts at once: a bad file would fail before any limit)."""
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=60, height_mm=10)
    proc = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "out", time_limit_s=0.3,
                       memory_mb=4096)
    import time
    while (result := proc.poll()) is None:
        time.sleep(0.02)
    assert result["code"] == "plan.time_limit" and "limit" in result["text"]
    assert proc.proc.poll() is not None


def test_plan_memory_limit_fails_the_plan(tmp_path):
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=15, height_mm=3)
    proc = PlanProcess("j1", src, "generic-0.5mm", tmp_path / "out", time_limit_s=120,
                       memory_mb=200)
    proc.proc.wait(120)
    result = proc.poll()
    assert not result["ok"] and result["code"] == "plan.memory_limit", result


def _alive(pid):
    """True while ``pid`` runs (a zombie waiting for its reaper counts as gone)."""
    try:
        with open("/proc/%d/status" % pid) as f:
            return not any(line.startswith("State:") and "Z" in line for line in f)
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_plan_dies_with_the_daemon_that_started_it(tmp_path):
    import signal
    import time
    from daemon_helpers import write_dome
    src = write_dome(tmp_path / "dome.npy", diameter_mm=120, height_mm=20)   # plans for ~10 s
    starter = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\n"
         "from hostd.planning import PlanProcess\n"
         "p = PlanProcess('j1', sys.argv[1], 'generic-0.5mm', sys.argv[2], 120, 4096)\n"
         "print(p.pid, flush=True)\n"
         "time.sleep(120)\n", str(src), str(tmp_path / "out")],
        cwd=ROOT, stdout=subprocess.PIPE, text=True)
    plan_pid = int(starter.stdout.readline())
    try:
        time.sleep(1.0)                      # the plan is under way
        assert _alive(plan_pid)
        starter.send_signal(signal.SIGKILL)  # the daemon is killed outright
        starter.wait(10)
        deadline = time.monotonic() + 5
        while _alive(plan_pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(plan_pid), "the plan outlived the daemon that started it"
    finally:
        if _alive(plan_pid):
            os.kill(plan_pid, signal.SIGKILL)


def test_a_full_disk_fails_the_plan_with_its_own_code_and_frees_the_partial_outputs(tmp_path):
    # The planner as a child would run it, with the disk filling up while it writes.
    outdir = tmp_path / "outbox" / ".cache" / ".tmp-j1"
    outdir.mkdir(parents=True)
    child = ("import errno, sys\n"
             "from pathlib import Path\n"
             "from hostd import planner, planning\n"
             "def full(path, profile, outdir, progress=None, keep=None):\n"
             "    (Path(outdir) / 'dome.gcode').write_bytes(b'G1 X1\\n' * 1000)\n"
             "    raise OSError(errno.ENOSPC, 'No space left on device')\n"
             "planner.run = full\n"
             "sys.exit(planning.child_main(sys.argv[1:]))\n")
    args = json.dumps({"input": "dome.npy", "profile": "generic-0.5mm", "outdir": str(outdir)})
    r = subprocess.run([sys.executable, "-c", child, args], cwd=ROOT, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    result = json.loads((outdir / "result.json").read_text())
    assert result["code"] == "plan.disk_full" and not result["ok"]
    mount = tmp_path.resolve()
    while not os.path.ismount(mount):
        mount = mount.parent
    assert "the disk mounted at %s, " % mount in result["text"] and "outbox_dir" in result["fix"]
    assert sorted(p.name for p in outdir.iterdir()) == ["result.json"]


def test_a_plan_marked_not_printable_fails_its_job_with_the_reasons():
    from hostd.planning import plan_result
    from pipeline.plan import Plan
    plan = Plan(name="x", profile=None)
    assert plan_result(plan) == {"ok": True}
    plan.problems.append({"code": "flatten.invalid_edges", "message": "12 % invalid",
                          "fix": "simplify"})
    assert plan_result(plan) == {"ok": True}        # a warning alone still prints
    plan.problems.append({"code": "flatten.overlap", "message": "the layout folds",
                          "fix": "raise min_prominence_mm"})
    r = plan_result(plan)
    assert r["ok"] is False and r["code"] == "flatten.overlap"
    assert "the layout folds" in r["text"] and "12 % invalid" in r["text"]
    assert "min_prominence_mm" in r["fix"]
