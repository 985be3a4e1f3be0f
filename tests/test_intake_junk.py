"""Files dropped by the thousand are taken a slice at a time, so the run loop goes round
(plans, prints, the heartbeat) between slices."""

from daemon_helpers import in_process_daemon
from hostd import intake


def test_many_files_are_taken_a_slice_per_round(tmp_path, monkeypatch):
    monkeypatch.setattr(intake, "SLICE_S", 0.0)      # one file per round
    d = in_process_daemon(tmp_path, 0, settle_s=0.0, poll_s=3600.0)
    try:
        d.watcher.stop()      # no events: only the loop's own wake-up may scan again
        for name in ("a.npy", "b.png", "c.tif"):
            (d.config.drop_dir / name).write_bytes(b"junk")
        counts = []
        for _ in range(3):
            d.tick()
            counts.append(len(d.store.list()))
        assert counts == [1, 2, 3]
    finally:
        d.shutdown()
