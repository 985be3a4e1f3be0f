"""A node status file planted on the share with fields of the wrong types, or a link that
is no web address, neither breaks the farm page nor becomes a link."""

import json
import time

from hostd.outputs import atomic_write
from hostd.status import status_fields, web_link
from test_web_api import Node


def test_planted_status_files_of_bad_types_show_without_breaking_the_page(tmp_path):
    n = Node(tmp_path)
    nodes = n.config.drop_dir / ".hostd" / "nodes"
    now = time.time()
    atomic_write(nodes / "evil.json", json.dumps({
        "node_id": ["x"], "state": {"a": 1}, "last_seen": "soon", "queue_length": "many",
        "web_url": "javascript:alert(document.cookie)", "problem": ["<script>"],
        "printers": [{"name": 5, "state": [1], "paused": "yes", "job": {"id": 1},
                      "progress": "half"}, "not a printer", None]}))
    atomic_write(nodes / "data.json", json.dumps({
        "state": "running", "web_url": "data:text/html,<script>alert(1)</script>",
        "printers": {"p": 1}, "queue_length": 1e300}))
    atomic_write(nodes / "good.json", json.dumps({
        "state": "running", "last_seen": now, "queue_length": 1,
        "web_url": "https://good.local:8080/", "printers": [
            {"name": "mk3", "state": "printing", "paused": False, "job": "j1",
             "progress": 0.5}]}))
    r = n.client.get("/farm")
    assert r.status_code == 200
    html = r.get_data(as_text=True)
    assert "javascript:" not in html and "data:text" not in html
    assert '<a href="https://good.local:8080/">good</a>' in html
    assert 'data-node="evil"' in html and 'data-node="data"' in html
    n.store.close()


def test_status_fields_keep_types_and_bound_text():
    got = status_fields({"state": "x" * 10000, "pid": -3, "queue_length": True,
                         "planning": ["a", 3, "b"], "printers": [{"progress": 7}],
                         "extra": "y" * 10 ** 6})
    assert len(got["state"]) == 200 and got["pid"] is None and got["queue_length"] is None
    assert got["planning"] == ["a", "b"] and got["printers"][0]["progress"] is None
    assert "extra" not in got
    for bad in ("javascript:alert(1)", "JAVASCRIPT:x", "data:,x", "//evil", "http://", 5):
        assert web_link(bad) is None, bad
    assert web_link("http://n1.local:8080/") == "http://n1.local:8080/"
