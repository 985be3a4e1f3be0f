"""What the drop folder's names mean: a file dropped (or uploaded) under the name of one
just taken is taken too; a sidecar beside two inputs of its stem is refused naming both;
names that would read otherwise than they are (a right-to-left override) are shown
escaped."""

import io
import os

import numpy as np

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from hostd.watcher import Watcher, name_problem, shown
from hostd.web.app import create_app


class Clock:
    t = 100.0

    def __call__(self):
        return self.t


def test_a_new_file_under_a_name_just_claimed_is_offered_again(tmp_path):
    clock = Clock()
    drop = tmp_path / "drop"
    drop.mkdir()
    w = Watcher(drop, settle_s=1.0, poll_s=0.5, clock=clock)
    f = drop / "a.npy"
    f.write_bytes(b"first")
    w.poll()
    clock.t += 2
    [c] = w.poll()
    os.rename(f, tmp_path / "claimed.npy")      # claimed: then a second one, same name,
    f.write_bytes(b"second")                    # before the next scan
    clock.t += 2
    w.poll()
    clock.t += 2
    [again] = w.poll()
    assert again.path == f and f.read_bytes() == b"second"
    clock.t += 2
    assert w.poll() == []                       # and once only


def test_ten_uploads_of_one_name_make_ten_jobs(tmp_path):
    d = in_process_daemon(tmp_path, 0, token="a-long-secret-for-uploads")
    try:
        d.plans.start = lambda: None            # taking them is the question, not planning
        client = create_app(d.config, d.store, d).test_client()
        auth = {"Authorization": "Bearer a-long-secret-for-uploads"}
        data = write_dome(tmp_path / "src" / "dome.npy").read_bytes()
        for i in range(10):
            r = client.post("/api/jobs", headers=auth, content_type="multipart/form-data",
                            data={"file": (io.BytesIO(data), "dome.npy")})
            assert r.status_code == 201, r.json
            tick_until(d, lambda: len(d.store.list()) == i + 1, timeout=30,
                       what="upload %d taken" % (i + 1))
        assert len(d.store.list()) == 10
    finally:
        d.shutdown()


def test_a_sidecar_beside_two_inputs_of_its_stem_is_refused_naming_both(tmp_path):
    from PIL import Image
    d = in_process_daemon(tmp_path, 0)
    try:
        drop = d.config.drop_dir
        write_dome(drop / "t.npy")
        Image.fromarray((np.load(drop / "t.npy") * 40).astype(np.uint8)).save(drop / "t.png")
        tick_until(d, lambda: len(d.store.list()) == 2 and all(
            j["state"] == J.FAILED for j in d.store.list()))
        for job in d.store.list():
            assert job["error_code"] == "sidecar.ambiguous"
            assert "t.npy" in job["error"] and "t.png" in job["error"]
            assert "Fix:" in job["error"]
        failed = d.config.failed_dir
        assert sorted(p.name for p in failed.iterdir() if not p.name.endswith(".txt")) \
            == ["t-2.png", "t.npy", "t.yaml"] or \
            sorted(p.name for p in failed.iterdir() if not p.name.endswith(".txt")) \
            == ["t-2.npy", "t.png", "t.yaml"]
    finally:
        d.shutdown()


def test_direction_changing_characters_in_names_are_shown_escaped(tmp_path, caplog):
    evil = "invoice\u202egnp.npy"
    assert name_problem(evil) and "U+202E" in name_problem(evil)
    assert shown(evil) == "invoice\\u202egnp.npy"
    assert shown("plain dome.npy") == "plain dome.npy" and name_problem("Kuppel é.npy") is None
    d = in_process_daemon(tmp_path, 0)
    try:
        write_dome(d.config.drop_dir / evil)
        client = create_app(d.config, d.store, d).test_client()
        tick_until(d, lambda: len(d.store.list()) == 1)
        [job] = d.store.list()
        assert "\u202e" not in job["name"] and "\u202e" not in job["rel_path"]
        assert job["rel_path"] == "invoice\\u202egnp.npy"
        page = client.get("/").get_data(as_text=True)
        assert "\u202e" not in page and job["name"] in page
        said = caplog.text
        assert "\u202e" not in said and "invoice\\u202egnp.npy" in said
    finally:
        d.shutdown()
