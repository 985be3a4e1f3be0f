"""`hostd run` end to end: real files, real processes, the simulator on a pty."""

import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from daemon_helpers import (SIM, all_files, belt_profile, cli_jobs, daemon, drop,
                            gcode_commands, hostd, jobs, states, wait_for, write_config)
from hostd.feed import job_feed
from printer_helpers import job_commands


@pytest.mark.slow
def test_three_files_one_invalid(tmp_path, dome, pty_sim):
    sim, port = pty_sim
    # A printer that clears its own bed: the two prints follow each other without a person.
    env = belt_profile(tmp_path / "profiles")
    cfg = write_config(tmp_path, printers=[{"name": "p1", "profile": "belt-0.5mm",
                                            "port": port, "baud": 250000}])
    share = tmp_path / "share"
    with daemon(cfg, env) as d:
        drop(dome, share / "drop", "first.npy")
        drop(dome, share / "drop", "second.npy")
        (share / "drop" / "broken.png").write_bytes(b"this is not a picture")
        wait_for(lambda: sorted(states(cfg).values()) == ["done", "done", "failed"],
                 timeout=120, what="two printed, one failed", proc=d)
        assert d.stop() == 0
    done = {j["name"]: j for j in jobs(cfg)}
    printed = sorted((j for j in done.values() if j["state"] == "done"),
                     key=lambda j: j["started_at"])
    expected = []
    for job in printed:
        gcode = next(Path(job["outbox"]).glob("*.gcode"))
        # Each job starts with its feed rate (full speed unless the link cannot keep up).
        expected += job_feed(gcode, 250000).commands + gcode_commands(gcode)
    assert job_commands(sim) == expected
    failed = share / "failed"
    reason = (failed / "broken.error.txt").read_text()
    assert "not .png data" in reason and "Fix:" in reason and ".claimed" not in reason
    assert (failed / "broken.png").read_bytes() == b"this is not a picture"
    day = time.strftime("%Y-%m-%d")
    for name in ("first", "second"):
        assert (share / "done" / day / (name + ".npy")).read_bytes() == dome.read_bytes()
        assert (share / "done" / day / (name + ".yaml")).exists()
    assert not [f for f in all_files(share / "drop") if not f.startswith(".")]
    # The journal tells each job's life, not only its claim and its failure.
    log = d.output()
    for job in printed:
        for line in ("job %s: %s ready (" % (job["id"], job["name"]),
                     "job %s: printing %s on p1 (copy 1 of 1)" % (job["id"], job["name"]),
                     "job %s: %s printed on p1 in" % (job["id"], job["name"])):
            assert line in log, line


def test_slow_copy_is_not_taken_early(tmp_path, dome):
    cfg = write_config(tmp_path, settle_s=1.5, poll_s=0.1)
    drop_dir = tmp_path / "share" / "drop"
    data = dome.read_bytes()
    with daemon(cfg) as d:
        wait_for(lambda: (tmp_path / "state" / "jobs.sqlite").exists(), what="daemon up", proc=d)
        shutil.copy(dome.with_name("dome.yaml"), drop_dir / "slow.yaml")
        chunks = 8
        with open(drop_dir / "slow.npy", "wb") as f:
            for i in range(chunks):
                f.write(data[i * len(data) // chunks:(i + 1) * len(data) // chunks])
                f.flush()
                time.sleep(0.5)             # over 3.5 s in all, each pause < settle_s
            last_write = time.time()
        [job] = wait_for(lambda: jobs(cfg), timeout=20, what="job", proc=d)
        assert job["created_at"] >= last_write, "taken before the copy was complete"
        wait_for(lambda: jobs(cfg)[0]["input_hash"], what="hash", proc=d)
        import hashlib
        assert jobs(cfg)[0]["input_hash"] == hashlib.sha256(data).hexdigest()
        assert d.stop() == 0


def test_bad_config_and_bad_sidecar(tmp_path, dome):
    bad = tmp_path / "bad.yaml"
    bad.write_text("node_id: x\npoll_s: often\n")
    r = hostd("run", "--config", bad, timeout=30)
    assert r.returncode == 2 and "poll_s" in r.stderr and str(bad) in r.stderr
    cfg = write_config(tmp_path / "n")
    drop_dir = tmp_path / "n" / "share" / "drop"
    with daemon(cfg) as d:
        drop_dir.mkdir(parents=True, exist_ok=True)
        (drop_dir / "odd.yaml").write_text("size_mm: big\n")
        shutil.copy(dome, drop_dir / "odd.npy")
        wait_for(lambda: states(cfg).get("odd.npy") == "failed", timeout=30, what="fail", proc=d)
        reason = (tmp_path / "n" / "share" / "failed" / "odd.error.txt").read_text()
        assert "size_mm" in reason and reason.startswith("odd.yaml: ")
        assert ".claimed" not in reason  # named as dropped, not by the claim folder
        assert (tmp_path / "n" / "share" / "failed" / "odd.yaml").exists()
        # A second daemon on the same state folder is refused clearly.
        r = hostd("run", "--config", cfg, timeout=30)
        assert r.returncode == 2 and "already runs" in r.stderr
        assert d.stop() == 0
    r = hostd("pause", "p1", "-c", cfg)
    assert r.returncode == 2 and "no hostd daemon runs" in r.stderr


@pytest.mark.slow
def test_runaway_plan_fails_its_job_only(tmp_path, dome):
    # A 16-megapixel field passes the input checks but, on a profile that keeps every
    # pixel (validate.working_pixel_mm: 0), needs far more memory than the plan limit:
    # its planning process dies, the other job is planned and printed.
    from pipeline.profiles.profile import find_profile
    keep_all = tmp_path / "keep-all-pixels.yaml"
    keep_all.write_text(find_profile("generic-0.5mm").read_text().replace(
        "working_pixel_mm: 0.25", "working_pixel_mm: 0"))
    cfg = write_config(tmp_path, planning={"workers": 2, "memory_mb": 700}, printers=[
        {"name": "p1", "profile": str(keep_all), "baud": 2000000,
         "port": SIM}])
    drop_dir = tmp_path / "share" / "drop"
    big = tmp_path / "in" / "huge.npy"
    big.parent.mkdir(parents=True, exist_ok=True)
    y, x = np.mgrid[0:4000, 0:4000].astype(np.float32)
    np.save(big, 20.0 * np.exp(-((x - 2000) ** 2 + (y - 2000) ** 2) / 1.6e6).astype(np.float32))
    (tmp_path / "in" / "huge.yaml").write_text("pixel_mm: 0.05\n")
    with daemon(cfg) as d:
        drop(big, drop_dir, "huge.npy")
        drop(dome, drop_dir, "good.npy")
        wait_for(lambda: states(cfg) == {"huge.npy": "failed", "good.npy": "done"}
                 or states(cfg).get("good.npy") == "failed", timeout=120, what="done", proc=d)
        assert states(cfg)["good.npy"] == "done"
        reason = (tmp_path / "share" / "failed" / "huge.error.txt").read_text()
        assert "memory" in reason.lower() or "planning process" in reason
        assert d.stop() == 0


@pytest.mark.slow
def test_two_daemons_share_one_drop_folder(tmp_path, dome):
    share = tmp_path / "share"
    # Printers that clear their own beds: ten prints follow each other without a person.
    env = belt_profile(tmp_path / "profiles")
    belt = [{"name": "p1", "profile": "belt-0.5mm",
             "port": SIM, "baud": 2000000}]
    cfg_a = write_config(tmp_path / "a", node_id="a", share=share, printers=belt)
    cfg_b = write_config(tmp_path / "b", node_id="b", share=share, printers=belt)
    names = ["f%02d.npy" % i for i in range(10)]
    with daemon(cfg_a, env) as a, daemon(cfg_b, env) as b:
        status = share / "drop" / ".hostd" / "nodes"
        wait_for(lambda: {p.stem for p in status.glob("*.json")} == {"a", "b"}, timeout=30,
                 what="both nodes up", proc=a)
        for name in names:
            drop(dome, share / "drop", name)

        def finished():
            sa, sb = states(cfg_a), states(cfg_b)
            return len(sa) + len(sb) == 10 and set(sa.values()) | set(sb.values()) == {"done"}
        wait_for(finished, timeout=170, what="10 printed", proc=a)
        assert a.stop() == 0 and b.stop() == 0
    printed = [j["name"] for j in jobs(cfg_a) + jobs(cfg_b)]
    assert sorted(printed) == names           # each exactly once
    # Neither node hoards the queue: each holds claim_ahead (2) per printer at a time.
    assert len(jobs(cfg_a)) >= 2 and len(jobs(cfg_b)) >= 2
    assert cli_jobs(cfg_a) == jobs(cfg_a)     # `hostd jobs --json` shows the same rows
    day = share / "done" / time.strftime("%Y-%m-%d")
    assert sorted(p.name for p in day.glob("*.npy")) == names
    nodes = {p.stem for p in (share / "drop" / ".hostd" / "nodes").glob("*.json")}
    assert nodes == {"a", "b"}
