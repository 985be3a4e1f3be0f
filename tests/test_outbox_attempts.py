"""Each attempt's outputs replace the last attempt's as a whole: after a requeue the job's
outbox holds exactly what the new attempt made, and a failed plan's files are listed."""

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J


def test_a_requeued_job_shows_only_the_new_attempts_files(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        path = write_dome(d.config.drop_dir / "dome.npy")
        # Far larger than the bed: the plan fails with an error file in the outbox.
        path.with_name("dome.yaml").write_text("size_mm: 5000\n")
        job = lambda: d.store.list()[0]                      # noqa: E731
        tick_until(d, lambda: d.store.list() and job()["state"] == J.FAILED, what="the failure")
        first = job()
        assert first["outbox"], "a failed plan's outputs are the job's"
        from pathlib import Path
        outbox = Path(first["outbox"])
        assert (outbox / "dome.error.json").exists()
        (Path(d.config.failed_dir) / "dome.yaml").write_text("size_mm: 20\n")
        assert d.control.requeue(first["id"]).startswith("requeued")
        tick_until(d, lambda: job()["state"] in (J.READY, J.PRINTING, J.DONE), what="the new plan")
        names = sorted(f.name for f in outbox.iterdir())
        assert "dome.error.json" not in names and "dome.gcode" in names
    finally:
        d.shutdown()
