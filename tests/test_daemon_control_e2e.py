"""A running daemon stopped, restarted and steered end to end: killed while planning or
printing, a print stopped on the printer, paused from the terminal, copies."""

import contextlib
import shutil
import signal
import time
from pathlib import Path

import pytest

from daemon_helpers import (daemon, drop, gcode_commands, hostd, jobs,
                            states, wait_for, write_config)
from hostd.feed import job_feed
from printer_helpers import job_commands


@pytest.mark.slow
def test_kill_during_planning_then_restart_completes(tmp_path, dome):
    cfg = write_config(tmp_path)
    with daemon(cfg) as d:
        drop(dome, tmp_path / "share" / "drop", "dome.npy")
        wait_for(lambda: states(cfg).get("dome.npy") == "planning", timeout=20, proc=d,
                 what="planning")
        d.stop(signal.SIGKILL)
    assert states(cfg) == {"dome.npy": "planning"}
    with daemon(cfg) as d:
        wait_for(lambda: states(cfg) == {"dome.npy": "done"}, timeout=90, what="done", proc=d)
        assert d.stop() == 0
        assert "dome.npy was being planned when hostd stopped; planning it again" in d.output()
    kinds = [e for e in hostd("job", jobs(cfg)[0]["id"], "-c", cfg).stdout.splitlines()]
    assert any("restarted while planning" in k for k in kinds)


@pytest.mark.slow
def test_kill_during_printing_then_restart_is_interrupted(tmp_path, dome):
    slow = [{"name": "p1", "profile": "generic-0.5mm", "baud": 250000,
             "port": "sim://?time_scale=0&advanced_ok=1&boot_s=0&baud=115200"}]
    cfg = write_config(tmp_path, printers=slow)
    with daemon(cfg) as d:
        drop(dome, tmp_path / "share" / "drop", "dome.npy")
        wait_for(lambda: states(cfg).get("dome.npy") == "printing", timeout=60, proc=d,
                 what="printing")
        d.stop(signal.SIGKILL)
    with daemon(cfg) as d:
        wait_for(lambda: states(cfg) == {"dome.npy": "interrupted"}, timeout=20, proc=d,
                 what="interrupted")
        wait_for(lambda: "dome.npy was printing when hostd stopped" in d.output(), timeout=10,
                 proc=d, what="the recovery in the log")
        failed = tmp_path / "share" / "failed"
        assert (failed / "dome.npy").read_bytes() == dome.read_bytes()
        assert "requeue" in (failed / "dome.error.txt").read_text()
        # a person requeues it: the cached plan is ready, but the printer is held (the
        # interrupted print is still on its bed) until the person resumes it
        job_id = jobs(cfg)[0]["id"]
        r = hostd("requeue", job_id, "-c", cfg)
        assert r.returncode == 0, r.stderr
        wait_for(lambda: states(cfg) == {"dome.npy": "ready"}, timeout=30, proc=d,
                 what="ready again")
        time.sleep(2.0)
        assert states(cfg) == {"dome.npy": "ready"}
        r = hostd("resume", "p1", "-c", cfg)
        assert r.returncode == 0, r.stderr
        wait_for(lambda: states(cfg) == {"dome.npy": "printing"}, timeout=30, proc=d,
                 what="printing again")
        # SIGTERM during a print: stop feeding, park, interrupted, clean exit
        t = time.monotonic()
        assert d.stop() == 0
        assert time.monotonic() - t < 10.0
        assert "The print of dome.npy was interrupted: the daemon was stopped" in d.output()
    assert states(cfg) == {"dome.npy": "interrupted"}
    assert (tmp_path / "share" / "failed" / "dome.npy").exists()


@contextlib.contextmanager
def printing_dome(tmp_path, dome, port):
    """A daemon whose one printer is on ``port`` (a simulator's pty), printing ``dome``.

    Yields (config path, daemon process).
    """
    cfg = write_config(tmp_path, printers=[{"name": "p1", "profile": "generic-0.5mm",
                                            "port": port, "baud": 115200}])
    with daemon(cfg) as d:
        drop(dome, tmp_path / "share" / "drop", "dome.npy")
        wait_for(lambda: states(cfg).get("dome.npy") == "printing", timeout=60, proc=d,
                 what="printing")
        yield cfg, d


@pytest.mark.slow
def test_stop_print_on_the_printer_cancels_the_job(tmp_path, dome, pty_sim):
    sim, port = pty_sim
    with printing_dome(tmp_path, dome, port) as (cfg, d):
        sim.press("cancel")      # Marlin's "Stop print" on a host's print
        wait_for(lambda: states(cfg).get("dome.npy") == "cancelled", timeout=60, proc=d,
                 what="cancelled")
        assert d.stop() == 0
    reason = (tmp_path / "share" / "failed" / "dome.error.txt").read_text()
    assert "cancelled on the printer" in reason
    assert (tmp_path / "share" / "failed" / "dome.npy").read_bytes() == dome.read_bytes()
    assert "The print of dome.npy was cancelled on the printer" in d.output()


@pytest.mark.slow
def test_ctrl_c_during_a_print_still_runs_the_cancel_script(tmp_path, dome, pty_sim):
    """Ctrl-C in the terminal of `hostd run` reaches every process of its foreground
    group; the printer link must outlive it long enough for the daemon to send the cancel
    script (heaters off), not die with it and leave the printer hot."""
    from hostd.printer.settings import script_lines
    from pipeline.profiles.profile import load_profile

    sim, port = pty_sim
    cancel = script_lines(load_profile("generic-0.5mm").render_gcode("cancel"))
    with printing_dome(tmp_path, dome, port) as (cfg, d):
        d.ctrl_c()
        assert d.proc.wait(30) == 0
        d._out.close()
        wait_for(lambda: job_commands(sim)[-len(cancel):] == cancel, timeout=10,
                 what="the cancel script on the printer")
    assert "cancel failed" not in d.output()
    assert "The print of dome.npy was interrupted: the daemon was stopped" in d.output()


@pytest.mark.slow
def test_pause_and_resume_from_the_terminal_park_and_continue(tmp_path, dome, pty_sim):
    from hostd.printer.settings import script_lines
    from pipeline.profiles.profile import load_profile

    sim, port = pty_sim
    prof = load_profile("generic-0.5mm")
    park = script_lines(prof.render_gcode("pause"))
    unpark = script_lines(prof.render_gcode("resume"))
    with printing_dome(tmp_path, dome, port) as (cfg, d):
        r = hostd("pause", "p1", "-c", cfg)
        assert r.returncode == 0, r.stderr
        wait_for(lambda: job_commands(sim)[-len(park):] == park, timeout=30, proc=d,
                 what="the pause script run")
        before = len(sim.commands())
        time.sleep(1.0)
        assert len(sim.commands()) == before, "the printer was fed while paused"
        assert states(cfg)["dome.npy"] == "printing"
        r = hostd("resume", "p1", "-c", cfg)
        assert r.returncode == 0, r.stderr
        wait_for(lambda: states(cfg).get("dome.npy") == "done", timeout=120, proc=d,
                 what="done")
        assert d.stop() == 0
    job = jobs(cfg)[0]
    path = next(Path(job["outbox"]).glob("*.gcode"))
    gcode = job_feed(path, 115200).commands + gcode_commands(path)
    done = job_commands(sim)
    # Exactly the file, with the profile's park and unpark between two of its lines.
    k = next(i for i, (a, b) in enumerate(zip(done, gcode)) if a != b)
    assert done[k:k + len(park) + len(unpark)] == park + unpark
    assert done[:k] + done[k + len(park) + len(unpark):] == gcode


@pytest.mark.slow
def test_sidecar_copies_print_the_plan_that_many_times(tmp_path, dome, pty_sim):
    sim, port = pty_sim
    cfg = write_config(tmp_path, printers=[{"name": "p1", "profile": "generic-0.5mm",
                                            "port": port, "baud": 250000}])
    src = tmp_path / "in" / "two.npy"
    src.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(dome, src)
    side = dome.with_name(dome.stem + ".yaml").read_text()
    src.with_name("two.yaml").write_text(side + "copies: 2\n")
    with daemon(cfg) as d:
        drop(src, tmp_path / "share" / "drop", "two.npy")
        # Between two copies the printer waits until a person has taken the first off.
        wait_for(lambda: jobs(cfg) and jobs(cfg)[0]["copies_done"] == 1, timeout=120, proc=d,
                 what="the first copy printed")
        time.sleep(1.0)
        assert jobs(cfg)[0]["state"] == "ready" and jobs(cfg)[0]["copies_done"] == 1
        r = hostd("clear", "p1", "-c", cfg)
        assert r.returncode == 0, r.stderr
        wait_for(lambda: states(cfg).get("two.npy") == "done", timeout=120, proc=d,
                 what="two copies printed")
        assert d.stop() == 0
    job = jobs(cfg)[0]
    assert job["copies"] == 2 and job["copies_done"] == 2
    path = next(Path(job["outbox"]).glob("*.gcode"))
    gcode = job_feed(path, 250000).commands + gcode_commands(path)
    assert job_commands(sim) == gcode + gcode
