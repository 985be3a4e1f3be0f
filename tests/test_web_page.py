"""The page without JavaScript, the farm view from the nodes' status files, and waitress serving."""

import json
import os
import threading
import time

from daemon_helpers import in_process_daemon, write_dome
from hostd.outputs import atomic_write
from hostd.web.app import create_app
from hostd.web import server
from test_web_api import TOKEN, Node, make_config
from web_helpers import get_json, open_clients


def test_page_plain_html(tmp_path):
    n = Node(tmp_path)
    html = n.client.get("/").get_data(as_text=True)
    # Every action is a real form (works without JS), with a token field and, when
    # destructive, a confirmation box.
    assert 'action="/actions/printers/sim/pause"' in html
    assert 'action="/actions/jobs/%s/cancel"' % n.printing in html
    assert html.count('name="confirm"') >= 2
    assert '<progress max="1" value="0.5"' in html
    assert "layer <span data-field=\"layer\">2</span> of <span data-field=\"layers\">2</span>" \
        in html
    assert "/api/jobs/%s/files/dome.toolpath.png" % n.printing in html
    # Thumbnails are labelled and open full size.
    assert '<a href="/api/jobs/%s/files/dome.toolpath.png"' % n.printing in html
    assert "<figcaption>tool paths</figcaption>" in html
    assert "<figcaption>shrink of the flat sheet</figcaption>" in html
    for name in ("a.png", "b.png"):
        assert name in html
    assert TOKEN not in html
    csp = n.client.get("/").headers["Content-Security-Policy"]
    assert "default-src 'self'" in csp and "script-src 'self'" in csp
    for asset in ("/static/hostd.js", "/static/hostd.css"):
        assert n.client.get(asset).status_code == 200
    job = n.client.get("/jobs/" + n.printing).get_data(as_text=True)
    assert "dome.gcode" in job and "12.5" in job
    n.store.close()


def test_farm_view_marks_stale_nodes(tmp_path):
    n = Node(tmp_path)
    nodes = n.config.drop_dir / ".hostd" / "nodes"
    now = time.time()
    atomic_write(nodes / "n1.json", json.dumps({
        "node_id": "n1", "state": "running", "last_seen": now, "queue_length": 2,
        "web_url": "http://n1.local:8080/", "problem": "jobs.sqlite: cannot record jobs",
        "printers": [{"name": "sim", "state": "printing", "paused": False, "job": "j1",
                      "progress": 0.42}]}))
    atomic_write(nodes / "old<b>.json", json.dumps({
        "node_id": "old", "state": "running", "last_seen": now - 3600, "queue_length": 0,
        "printers": [{"name": "mk3", "state": "idle", "paused": False, "job": None}]}))
    os.utime(nodes / "old<b>.json", (now - 3600,) * 2)    # not written for an hour
    atomic_write(nodes / "broken.json", "{not json")
    html = n.client.get("/farm").get_data(as_text=True)
    assert '<a href="http://n1.local:8080/">n1</a>' in html
    assert "42 %" in html and "queue 2" in html
    assert '<p class="note problem">jobs.sqlite: cannot record jobs</p>' in html
    assert 'class="node stale" data-node="old&lt;b&gt;"' in html
    assert "<b>.json" not in html and "old<b>" not in html
    assert html.count("stale") >= 2 and "broken" not in html
    assert "last seen 1:00:00 ago" in html and "last seen 0:00 ago" in html
    n.store.close()


def _served(tmp_path):
    from dataclasses import replace
    config = make_config(tmp_path)
    config = replace(config, web=replace(config.web, port=0))
    for d in ("drop_dir", "state_dir", "outbox_dir"):
        getattr(config, d).mkdir(parents=True, exist_ok=True)
    return server.start(config)


def test_the_page_answers_while_many_clients_trickle_headers(tmp_path):
    web = _served(tmp_path)
    slow = []
    try:
        # More than waitress's default connection limit, each sending its headers slowly.
        slow = open_clients(web, b"GET / HTTP/1.1\r\nHost: localhost\r\nX-Slow: ", 150)
        status, body = get_json(web.url + "healthz", timeout=5)
        assert status == 200 and body["ok"] is True
    finally:
        for s in slow:
            s.close()
        web.stop()


def test_waitress_serves_and_stops(tmp_path):
    from dataclasses import replace
    web = _served(tmp_path)
    config = make_config(tmp_path)
    assert web is not None and web.url.startswith("http://127.0.0.1:")
    try:
        status, body = get_json(web.url + "api/status")
        assert status == 200 and body["node_id"] == "n1"
        status, body = get_json(web.url + "api/jobs/x/cancel", method="POST")
        assert status == 401
        # A second server on the same port is refused with a log line, not an exception.
        busy = replace(config, web=replace(config.web, port=int(web.url.rsplit(":", 1)[1][:-1])))
        assert server.start(busy) is None
    finally:
        web.stop()
    assert not web.thread.is_alive()


def test_page_shows_inputs_in_the_drop_folder_that_are_no_job_yet(tmp_path):
    """A file being copied, and one left for another node, are on the page and in
    /api/status; a file claimed leaves the list for the queue."""
    d = in_process_daemon(tmp_path, time_scale=0, settle_s=0.5)
    client = create_app(d.config, store=d.store, daemon=d).test_client()
    drop = d.config.drop_dir
    try:
        write_dome(drop / "elsewhere" / "left.npy")     # no printer or profile of this node
        deadline = time.monotonic() + 10
        while ("elsewhere/left.npy", True) not in {i[::2] for i in d.watcher.inputs}:
            assert time.monotonic() < deadline, d.watcher.inputs
            d.tick()
            time.sleep(0.05)
        write_dome(drop / "new.npy")
        d.watcher.wake.set()
        d.tick()
        status = client.get("/api/status").get_json()
        assert {(f["file"], f["complete"], f["this_node"]) for f in status["drop_folder"]} == {
            ("elsewhere/left.npy", True, False), ("new.npy", False, True)}
        assert all(f["bytes"] > 0 for f in status["drop_folder"])
        html = client.get("/").get_data(as_text=True)
        assert "new.npy" in html and "still being copied" in html
        assert "elsewhere/left.npy" in html and "names no printer or profile of this node" in html

        deadline = time.monotonic() + 10
        while not d.store.list():
            assert time.monotonic() < deadline
            d.tick()
            time.sleep(0.05)
        after = client.get("/api/status").get_json()
        assert [f["file"] for f in after["drop_folder"]] == ["elsewhere/left.npy"]
        assert after["signature"] != status["signature"]
    finally:
        d.shutdown()


def test_page_shows_a_file_left_for_a_free_printer_while_peers_share_the_folder(
        tmp_path, monkeypatch):
    d = in_process_daemon(tmp_path, time_scale=0, claim_ahead=1)
    monkeypatch.setattr(d.farm, "live_peers", lambda: ["n2"])
    client = create_app(d.config, store=d.store, daemon=d).test_client()
    try:
        for name in ("a.npy", "b.npy"):
            write_dome(d.config.drop_dir / name)
        deadline = time.monotonic() + 10
        while not d.store.list():
            assert time.monotonic() < deadline
            d.tick()
            time.sleep(0.05)
        taken = d.store.list()[0]["name"]
        left = client.get("/api/status").get_json()["drop_folder"]
        assert [(f["file"], f["complete"], f["this_node"]) for f in left] == [
            ({"a.npy": "b.npy", "b.npy": "a.npy"}[taken], True, True)]
        assert "waiting for a printer" in client.get("/").get_data(as_text=True)
        farm = client.get("/farm").get_data(as_text=True)
        assert "not taken by any node yet: 1 waiting, 0 still being copied" in farm
    finally:
        d.shutdown()


def test_a_share_that_does_not_answer_does_not_hang_the_page(tmp_path, monkeypatch):
    """The outboxes are on a share that stopped answering (an NFS server rebooting):
    the page answers without their files, at once after the first read gave up, and
    shows them again once the share is back."""
    from hostd.web import view as view_mod
    n = Node(tmp_path)
    gate = threading.Event()
    listing = view_mod.outbox_files

    def hanging(outbox):
        gate.wait(30)
        return listing(outbox)

    monkeypatch.setattr(view_mod, "outbox_files", hanging)
    try:
        t = time.monotonic()
        first = n.client.get("/api/status")
        assert first.status_code == 200 and time.monotonic() - t < 5
        job = next(j for j in first.get_json()["queue"] + [
            p["job"] for p in first.get_json()["printers"] if p["job"]] if j["id"] == n.printing)
        assert job["files"] == []
        t = time.monotonic()
        assert n.client.get("/").status_code == 200 and time.monotonic() - t < 1.0
    finally:
        gate.set()
    time.sleep(0.2)
    status = n.client.get("/api/status").get_json()
    printing = [p["job"] for p in status["printers"] if p["job"]][0]
    assert "dome.gcode" in printing["files"] and printing["layers"] == 2
    n.store.close()
