"""Terrain end to end: the shipped generated terrain (hills with saddles and valleys,
planned with the free method its sidecar names) is planned, printed on the simulated
printer and filed in done/."""

import json
import shutil
import time
from pathlib import Path

import pytest

from daemon_helpers import in_process_daemon
from hostd import jobs as J

EXAMPLES = Path(__file__).resolve().parents[1] / "hostd" / "examples"


@pytest.mark.slow
def test_the_terrain_example_prints_and_is_filed(tmp_path):
    d = in_process_daemon(tmp_path, 0, baud=10_000_000)   # a fast wire: the print is not the point
    try:
        for name in ("hills.yaml", "hills.npy"):          # the sidecar first
            shutil.copy(EXAMPLES / name, d.config.drop_dir / name)
        deadline = time.monotonic() + 300
        while not (d.store.list() and d.store.list()[0]["state"] in J.FINISHED):
            assert time.monotonic() < deadline, "the terrain did not finish"
            d.tick()
            time.sleep(0.05)
        job = d.store.list()[0]
        assert job["state"] == J.DONE, job["error"]
        report = json.loads(next(Path(job["outbox"]).glob("*.report.json")).read_text())
        assert report["flatten"]["method"] == "free" and report["printable"]
        day = time.strftime("%Y-%m-%d")
        assert (Path(d.config.done_dir) / day / "hills.npy").exists()
    finally:
        d.shutdown()


TERRAIN = Path(__file__).resolve().parents[2] / "shared" / "data" / "terrain"


@pytest.mark.slow
def test_a_real_terrain_tile_at_40_mm_is_printed_once_a_person_decides(tmp_path):
    src = TERRAIN / "vancouver_island_south.png"
    if not src.exists():
        pytest.skip("the shared terrain is not here (%s)" % TERRAIN)
    d = in_process_daemon(tmp_path, 0, baud=10_000_000)   # a fast wire: the print is not the point
    try:
        (d.config.drop_dir / "tile.yaml").write_text("size_mm: 40\nmax_fill_mm: 5.0\n"
                                                     "method: free\n")
        shutil.copy(src, d.config.drop_dir / "tile.png")
        job = lambda: d.store.list()[0]                      # noqa: E731
        deadline = time.monotonic() + 300
        while not (d.store.list() and (job()["state"] in J.FINISHED or job()["decision"])):
            assert time.monotonic() < deadline, "the tile was not planned"
            d.tick()
            time.sleep(0.05)
        if job()["decision"]:          # outside the printable limits: a person prints it anyway
            assert job()["state"] == J.READY
            d.control.approve(job()["id"])
        while job()["state"] not in J.FINISHED:
            assert time.monotonic() < deadline, "the tile was not printed"
            d.tick()
            time.sleep(0.05)
        assert job()["state"] == J.DONE, job()["error"]
        assert (Path(d.config.done_dir) / time.strftime("%Y-%m-%d") / "tile.png").exists()
    finally:
        d.shutdown()
