"""While a plan runs, its stage and time so far show in /api/status, on the page and in
``hostd jobs``, from the plan process itself (not ``planning 0%`` for a minute)."""

import argparse
import time

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import plans as plans_mod
from hostd import jobs as J
from hostd.commands import jobs as cli
from hostd.web.app import create_app

STAGES = ("load", "validate", "mesh", "flatten", "simulate", "toolpath", "write")


def test_the_plans_stage_is_shown_while_it_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(plans_mod, "STAGE_S", 0.1)
    d = in_process_daemon(tmp_path, 0)
    try:
        write_dome(d.config.drop_dir / "dome.npy", diameter_mm=60, height_mm=8)
        client = create_app(d.config, d.store, d).test_client()
        seen, page, listed = set(), "", ""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            d.tick()
            time.sleep(0.05)
            queue = client.get("/api/status").json["queue"]
            if queue and queue[0]["state"] == J.PLANNING and queue[0]["stage"]:
                stage = queue[0]["stage"].split(",")[0]
                if stage in STAGES and stage not in seen:
                    seen.add(stage)
                    page = client.get("/").get_data(as_text=True)
                    monkeypatch.setattr(cli, "_open", lambda a, need_daemon: (None, d.store, 1))
                    cli.cmd_jobs(argparse.Namespace(state=None, json=False, config=None))
                    listed = capsys.readouterr().out
            if d.store.list() and d.store.list()[0]["state"] not in (J.QUEUED, J.PLANNING):
                break
        assert len(seen) >= 2, seen
        assert any(": %s, " % s in page for s in seen)
        assert "(planning: " in listed and " s)" in listed
        tick_until(d, lambda: d.store.list()[0]["outbox"], what="the plan's outputs")
        from pathlib import Path
        assert not (Path(d.store.list()[0]["outbox"]) / "stage.json").exists()
    finally:
        d.shutdown()
