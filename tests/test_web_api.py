"""The JSON API with Flask's test client: every endpoint, tokens, escaping, traversal, uploads."""

import dataclasses
import io
import json
import os
import threading
import time

import pytest

from hostd import jobs as J
from hostd.config import load_config
from hostd.web.app import create_app

TOKEN = "s3cret-token-for-tests"
EVIL = "<script>alert(1)</script>.png"      # a job name (from a share, a sidecar)
EVIL_FILE = "<img src=x onerror=alert(1)>.png"  # a file name (no '/' on disk)


def make_config(tmp_path, token=TOKEN):
    from dataclasses import replace
    base = load_config()
    return replace(base, node_id="n1", drop_dir=tmp_path / "drop", state_dir=tmp_path / "state",
                   outbox_dir=tmp_path / "outbox", done_dir=tmp_path / "done",
                   failed_dir=tmp_path / "failed", web=replace(base.web, token=token))


class Node:
    """A config, a store with jobs in several states, and outboxes with files."""

    def __init__(self, tmp_path, token=TOKEN):
        self.config = make_config(tmp_path, token)
        for d in ("drop_dir", "state_dir", "outbox_dir"):
            getattr(self.config, d).mkdir(parents=True, exist_ok=True)
        self.store = J.JobStore(self.config.db_path)
        s = self.store
        self.queued = s.add("a.png", "a.png", tmp_path / "a.png", profile="generic-0.5mm")
        self.queued2 = s.add("b.png", "b.png", tmp_path / "b.png", profile="generic-0.5mm")
        self.printing = s.add("dome.npy", "dome.npy", tmp_path / "dome.npy",
                              profile="generic-0.5mm")
        self.failed = s.add(EVIL, EVIL, tmp_path / "evil.png", profile="generic-0.5mm")
        out = self.config.outbox_dir / self.printing
        out.mkdir()
        (out / "dome.gcode").write_text(";LAYER_COUNT:2\nG28\n;LAYER:0\nG1 X1\nG1 X2\n;LAYER:1\n"
                                        "G1 X3\nG1 X4\n")
        (out / "dome.toolpath.png").write_bytes(b"\x89PNG fake")
        (out / "dome.stress.png").write_bytes(b"\x89PNG fake")
        (out / "dome.report.json").write_text(json.dumps(
            {"gcode": {"estimated_print_s": 100.0, "filament_mm": 12.5, "lines": 5}}))
        (tmp_path / "secret.txt").write_text("do not serve me")
        os.symlink(tmp_path / "secret.txt", out / "link.gcode")
        s.set_state(self.printing, J.PRINTING, printer="sim", outbox=str(out),
                    started_at=time.time() - 30, progress=0.5, last_line=7)
        evil_out = self.config.outbox_dir / self.failed
        evil_out.mkdir()
        (evil_out / EVIL_FILE).write_bytes(b"\x89PNG")
        s.set_state(self.failed, J.FAILED, "bad <b>input</b>", error="bad <b>input</b> <img src=x>",
                    outbox=str(evil_out))
        s.set_printer("sim", state="printing", paused=0, job_id=self.printing)
        self.app = create_app(self.config, store=s)
        self.app.config["HOSTD_ACTION_WAIT_S"] = 2.0
        self.client = self.app.test_client()

    def auth(self, token=TOKEN):
        return {"Authorization": "Bearer " + token}


@pytest.fixture
def node(tmp_path):
    n = Node(tmp_path)
    yield n
    n.store.close()


class Answerer(threading.Thread):
    """Stands in for the run loop: answers control requests and records them."""

    def __init__(self, db_path, ok=True):
        super().__init__(daemon=True)
        self.db_path, self.ok, self.seen, self.running = db_path, ok, [], True

    def run(self):
        store = J.JobStore(self.db_path)
        while self.running:
            for req in store.pending_requests():
                self.seen.append((req["action"], req["target"]))
                store.answer(req["id"], self.ok, "did %s %s" % (req["action"], req["target"]))
            time.sleep(0.01)
        store.close()


@pytest.fixture
def answerer(node):
    a = Answerer(node.config.db_path)
    a.start()
    yield a
    a.running = False
    a.join()


def test_healthz_and_status(node):
    r = node.client.get("/healthz")
    assert r.status_code == 200 and r.json["ok"] is True and r.json["node_id"] == "n1"
    s = node.client.get("/api/status").json
    assert s["node_id"] == "n1" and s["token_configured"] is True
    assert [p["name"] for p in s["printers"]] == ["sim"]
    p = s["printers"][0]
    assert p["state"] == "printing" and p["job"]["id"] == node.printing
    job = p["job"]
    assert job["progress"] == 0.5 and job["layers"] == 2 and job["layer"] == 2
    assert job["elapsed_s"] >= 29 and job["eta_s"] == pytest.approx(job["elapsed_s"], rel=0.01)
    assert job["images"] == {"toolpath": "dome.toolpath.png", "stress": "dome.stress.png"}
    assert [j["id"] for j in s["queue"]] == [node.queued, node.queued2]
    assert [j["id"] for j in s["recent"]] == [node.failed]
    assert s["counts"]["queued"] == 2 and s["counts"]["failed"] == 1
    assert TOKEN not in json.dumps(s)


def test_printers_and_jobs_filter(node):
    r = node.client.get("/api/printers")
    assert r.json["printers"][0]["name"] == "sim"
    all_ = node.client.get("/api/jobs").json["jobs"]
    assert {j["id"] for j in all_} == {node.queued, node.queued2, node.printing, node.failed}
    q = node.client.get("/api/jobs?state=queued").json["jobs"]
    assert {j["id"] for j in q} == {node.queued, node.queued2}
    both = node.client.get("/api/jobs?state=queued,failed").json["jobs"]
    assert len(both) == 3
    assert node.client.get("/api/jobs?state=bogus").status_code == 400


def test_job_detail_with_report(node):
    r = node.client.get("/api/jobs/" + node.printing)
    assert r.status_code == 200
    assert r.json["report"]["gcode"]["filament_mm"] == 12.5
    assert "dome.gcode" in r.json["files"] and "link.gcode" not in r.json["files"]
    assert [e["kind"] for e in r.json["events"]][-1] == "printing"
    assert node.client.get("/api/jobs/nope").status_code == 404
    # A prefix is not an id on the web (the CLI may guess, a URL must not).
    assert node.client.get("/api/jobs/" + node.printing[:-2]).status_code == 404


def test_download_from_a_share_that_does_not_answer_gives_503_not_a_held_thread(
        node, monkeypatch):
    """The outboxes' share stops answering (an NFS server rebooting): a download
    answers 503 with what to do within seconds instead of holding a server thread
    until the share is back; a share that stops in the middle of a download ends it.
    Once the share answers, the same download works."""
    from hostd.web import view as view_mod
    gate = threading.Event()
    confined = view_mod._open_confined

    def hanging(*args):
        gate.wait(30)
        return confined(*args)

    url = "/api/jobs/%s/files/dome.gcode" % node.printing
    monkeypatch.setattr(view_mod, "_open_confined", hanging)
    try:
        t = time.monotonic()
        r = node.client.get(url)
        assert r.status_code == 503 and time.monotonic() - t < 5
        assert "does not answer" in r.json["error"] and "try again" in r.json["error"]
        t = time.monotonic()
        assert node.client.get(url).status_code == 503 and time.monotonic() - t < 1
    finally:
        gate.set()
    time.sleep(0.2)
    monkeypatch.setattr(view_mod, "_open_confined", confined)
    whole = node.client.get(url)
    assert whole.status_code == 200 and b"LAYER:1" in whole.data
    assert whole.content_length == len(whole.data)

    stall = threading.Event()

    class Stalling(io.BytesIO):
        def read(self, n=-1):
            if self.tell():
                stall.wait(30)
            return super().read(min(n, 1000) if n and n > 0 else 1000)

    def stalling(*args):
        f, st = confined(*args)
        with f:
            return Stalling(f.read()), st

    monkeypatch.setattr(view_mod, "_open_confined", stalling)
    try:
        t = time.monotonic()
        r = node.client.get(url, buffered=False)
        with pytest.raises(OSError):
            b"".join(r.response)
        assert time.monotonic() - t < 5
    finally:
        stall.set()


def test_download_confined_to_outbox(node, tmp_path):
    base = "/api/jobs/%s/files/" % node.printing
    r = node.client.get(base + "dome.gcode")
    assert r.status_code == 200 and b"LAYER:1" in r.data
    assert r.content_length == len(r.data)
    assert "attachment" in r.headers["Content-Disposition"]
    # A resumed download asks for a range and gets exactly that part.
    part = node.client.get(base + "dome.gcode", headers={"Range": "bytes=5-14"})
    assert part.status_code == 206 and part.data == r.data[5:15]
    assert part.headers["Content-Range"] == "bytes 5-14/%d" % len(r.data)
    again = node.client.get(base + "dome.gcode", headers={"If-None-Match": r.headers["ETag"]})
    assert again.status_code == 304
    assert "sandbox" in r.headers["Content-Security-Policy"]
    assert node.client.get(base + "dome.toolpath.png").status_code == 200
    for bad in ("../secret.txt", "..%2Fsecret.txt", "..%2F..%2Fsecret.txt", "%2Fetc%2Fpasswd",
                "..", "link.gcode", ".hidden", "nope.gcode", "..%5Csecret.txt"):
        r = node.client.get(base + bad)
        assert r.status_code == 404, bad
        assert b"do not serve me" not in r.data
    r = node.client.get("/api/jobs/%s/files/%s" % ("..", "secret.txt"))
    assert r.status_code == 404
    # An outbox row pointing outside outbox_dir is refused too.
    node.store.update(node.queued, outbox=str(tmp_path))
    assert node.client.get("/api/jobs/%s/files/secret.txt" % node.queued).status_code == 404


def test_malicious_filename_escaped(node):
    page = node.client.get("/").get_data(as_text=True)
    assert "<script>alert(1)</script>" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;.png" in page
    assert "<b>input</b>" not in page and "<img src=x>" not in page
    detail = node.client.get("/jobs/" + node.failed).get_data(as_text=True)
    assert "<script>alert(1)</script>" not in detail and "&lt;script&gt;" in detail
    assert "<img src=x onerror" not in detail and "&lt;img src=x onerror=alert(1)&gt;.png" in detail
    assert "%3Cimg%20src=x%20onerror=alert(1)%3E.png" in detail   # the link is URL-encoded
    import urllib.parse
    r = node.client.get("/api/jobs/%s/files/%s" % (node.failed, urllib.parse.quote(EVIL_FILE)))
    assert r.status_code == 200 and r.data == b"\x89PNG"
    assert "sandbox" in r.headers["Content-Security-Policy"]


@pytest.mark.parametrize("method,url", [
    ("post", "/api/jobs/{q}/cancel"), ("post", "/api/jobs/{q}/requeue"),
    ("post", "/api/jobs/{p}/pause"), ("post", "/api/jobs/{p}/resume"),
    ("post", "/api/printers/sim/estop"), ("post", "/api/printers/sim/pause"),
    ("post", "/api/jobs/{q}/move"), ("post", "/api/queue"), ("post", "/api/jobs")])
def test_actions_refused_without_token(node, method, url):
    url = url.format(q=node.queued, p=node.printing)
    r = getattr(node.client, method)(url)
    assert r.status_code == 401 and "token" in r.json["error"]
    assert r.headers["WWW-Authenticate"].startswith("Bearer")
    r = getattr(node.client, method)(url, headers=node.auth("wrong"))
    assert r.status_code == 401
    assert node.store.pending_requests() == []


def test_actions_refused_when_no_token_configured(tmp_path):
    n = Node(tmp_path, token=None)
    r = n.client.post("/api/jobs/%s/cancel" % n.queued, headers=n.auth("anything"))
    assert r.status_code == 403 and "web: {token:" in r.json["error"]
    r = n.client.post("/actions/jobs/%s/cancel" % n.queued, data={"token": "", "confirm": "yes"})
    assert r.status_code == 403 and "web: {token:" in r.get_data(as_text=True)
    assert "Actions are off" in n.client.get("/").get_data(as_text=True)
    assert n.store.pending_requests() == []
    n.store.close()


def test_actions_go_through_control_table(node, answerer):
    h = node.auth()
    r = node.client.post("/api/jobs/%s/cancel" % node.queued, headers=h)
    assert r.status_code == 200 and r.json == {"ok": True, "result": "did cancel %s" % node.queued}
    assert node.client.post("/api/jobs/%s/pause" % node.printing, headers=h).status_code == 200
    assert node.client.post("/api/jobs/%s/resume" % node.printing, headers=h).status_code == 200
    assert node.client.post("/api/jobs/%s/requeue" % node.failed, headers=h).status_code == 200
    assert node.client.post("/api/printers/sim/estop", headers=h).status_code == 200
    r = node.client.post("/api/jobs/%s/move" % node.queued2, headers=h, json={"to": "top"})
    assert r.status_code == 200
    r = node.client.post("/api/queue", headers=h, json={"order": [node.queued2, node.queued]})
    assert r.status_code == 200
    assert answerer.seen == [("cancel", node.queued), ("pause", "sim"), ("resume", "sim"),
                             ("requeue", node.failed), ("estop", "sim"),
                             ("reorder", json.dumps([node.queued2, node.queued])),
                             ("reorder", json.dumps([node.queued2, node.queued]))]


def test_action_errors(node, answerer):
    h = node.auth()
    assert node.client.post("/api/jobs/nope/cancel", headers=h).status_code == 404
    assert node.client.post("/api/printers/nope/estop", headers=h).status_code == 404
    r = node.client.post("/api/jobs/%s/pause" % node.queued, headers=h)
    assert r.status_code == 409 and "not printing" in r.json["error"]
    assert node.client.post("/api/jobs/%s/explode" % node.queued, headers=h).status_code == 404
    r = node.client.post("/api/queue", headers=h, json={"order": [node.failed]})
    assert r.status_code == 409
    assert answerer.seen == []
    answerer.ok = False
    r = node.client.post("/api/jobs/%s/cancel" % node.queued, headers=h)
    assert r.status_code == 409 and r.json["ok"] is False


def test_action_without_daemon_answer_is_202(node):
    node.app.config["HOSTD_ACTION_WAIT_S"] = 0.1
    r = node.client.post("/api/jobs/%s/cancel" % node.queued, headers=node.auth())
    assert r.status_code == 202 and r.json["ok"] is None
    assert node.store.pending_requests()[0]["action"] == "cancel"


def test_form_actions_without_js(node, answerer):
    r = node.client.post("/actions/jobs/%s/cancel" % node.queued, data={"token": TOKEN})
    assert r.status_code == 400 and "confirm" in r.get_data(as_text=True)
    r = node.client.post("/actions/jobs/%s/cancel" % node.queued, data={"token": "bad",
                                                                       "confirm": "yes"})
    assert r.status_code == 401
    r = node.client.post("/actions/jobs/%s/cancel" % node.queued, data={"token": TOKEN,
                                                                       "confirm": "yes"})
    assert r.status_code == 200 and "did cancel" in r.get_data(as_text=True)
    r = node.client.post("/actions/printers/sim/pause", data={"token": TOKEN})
    assert r.status_code == 200
    assert answerer.seen == [("cancel", node.queued), ("pause", "sim")]
    assert TOKEN not in r.get_data(as_text=True)


def test_upload_atomic_into_drop(node):
    data = {"file": (io.BytesIO(b"\x93NUMPY fake"), "dome.npy"),
            "sidecar": (io.BytesIO(b"pixel_mm: 0.5\n"), "whatever.yaml")}
    r = node.client.post("/api/jobs", headers=node.auth(), data=data,
                         content_type="multipart/form-data")
    assert r.status_code == 201, r.json
    drop = node.config.drop_dir
    assert (drop / "dome.npy").read_bytes() == b"\x93NUMPY fake"
    assert (drop / "dome.yaml").read_text() == "pixel_mm: 0.5\n"
    assert not list(drop.glob("*.part"))
    # Same name again: a new name, never over the first.
    r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                         data={"file": (io.BytesIO(b"2"), "dome.npy")})
    assert r.status_code == 201 and r.json["name"] == "dome-2.npy"
    # Into a printer's folder; unknown folders and traversal refused.
    r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                         data={"file": (io.BytesIO(b"3"), "x.png"), "printer": "sim"})
    assert r.status_code == 201 and (drop / "sim" / "x.png").exists()
    r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                         data={"file": (io.BytesIO(b"3"), "x.png"), "printer": "../etc"})
    assert r.status_code == 400
    r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                         data={"file": (io.BytesIO(b"3"), "../../evil.png")})
    assert r.status_code == 201 and r.json["path"] == "evil.png"
    for bad in ("notes.txt", ".hidden.png", "a\x01b.png"):
        r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                             data={"file": (io.BytesIO(b"3"), bad)})
        assert r.status_code == 400, bad


def test_upload_to_a_drop_folder_that_does_not_answer_is_refused_and_never_lands(
        node, monkeypatch):
    """The drop folder is on a share that stopped answering: the upload answers 503
    within its wait instead of holding a server thread, and when the share comes back
    the abandoned upload does not land after all (the person was told it did not)."""
    from hostd.web import uploads as api_mod
    gate = threading.Event()
    real_save = api_mod.unique_path

    def hanging(path):
        gate.wait(30)
        return real_save(path)

    node.app.config["HOSTD_SHARE_WRITE_S"] = 1.0
    monkeypatch.setattr(api_mod, "unique_path", hanging)
    drop = node.config.drop_dir
    try:
        t = time.monotonic()
        r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                             data={"file": (io.BytesIO(b"\x93NUMPY fake"), "late.npy")})
        assert r.status_code == 503 and time.monotonic() - t < 5
        assert "does not answer" in r.json["error"] and "not taken" in r.json["error"]
    finally:
        gate.set()
    time.sleep(0.5)
    assert not list(drop.glob("late*")), list(drop.iterdir())
    monkeypatch.setattr(api_mod, "unique_path", real_save)
    r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                         data={"file": (io.BytesIO(b"\x93NUMPY fake"), "late.npy")})
    assert r.status_code == 201 and (drop / "late.npy").read_bytes() == b"\x93NUMPY fake"


def test_an_upload_the_watcher_would_ignore_is_refused(node):
    for name in ("~$lock.npy", "~$dome.png"):
        r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                             data={"file": (io.BytesIO(b"\x93NUMPY"), name)})
        assert r.status_code == 400 and "ignores" in r.json["error"], name
    # The other names the watcher passes over are refused too, each with its reason.
    for name in (".~lock.dome.npy", ".dome.npy", "dome.npy.part", "dome.npy.crdownload",
                 "dome.npy~"):
        r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                             data={"file": (io.BytesIO(b"\x93NUMPY"), name)})
        assert r.status_code == 400 and r.json["ok"] is False and r.json["error"], name
    assert not [p for p in node.config.drop_dir.rglob("*") if p.is_file()]


def test_upload_size_limit(node):
    node.app.config["MAX_CONTENT_LENGTH"] = 1000
    r = node.client.post("/api/jobs", headers=node.auth(), content_type="multipart/form-data",
                         data={"file": (io.BytesIO(b"x" * 5000), "big.png")})
    assert r.status_code == 413 and "larger" in r.json["error"]
    assert not (node.config.drop_dir / "big.png").exists()


def test_slow_readers_of_a_large_file_leave_the_page_up(node):
    from hostd.web import server
    from web_helpers import get_json, open_clients
    big = node.config.outbox_dir / node.printing / "big.gcode"
    big.write_bytes(b"G1 X1 Y1 E0.1\n" * (3 << 20))           # 42 MB: more than waitress
                                                                 # buffers by default
    config = dataclasses.replace(node.config, web=dataclasses.replace(node.config.web, port=0))
    web = server.start(config, store=node.store)
    readers = []
    try:
        readers = open_clients(web, b"GET /api/jobs/%s/files/big.gcode HTTP/1.1\r\nHost: localhost"
                                    b"\r\n\r\n" % node.printing.encode(),
                               server.THREADS + 2, rcvbuf=4096)      # each reads nothing
        # The threads hand the files to the server's buffer and are free again; before,
        # each waited for its reader, and the page never answered while they held.
        status, body = get_json(web.url + "healthz", timeout=60)
        assert status == 200 and body["ok"] is True
    finally:
        for s in readers:
            s.close()
        web.stop()


def test_unknown_api_path_is_json_404(node):
    r = node.client.get("/api/nothing")
    assert r.status_code == 404 and r.json["ok"] is False


class _FakePrinter:
    def __init__(self):
        self.estops = 0

    def estop(self):
        self.estops += 1


def test_control_estop_and_reorder_handlers(node):
    """The run loop's side: estop reaches the printer and holds it; reorder sets priorities."""
    from types import SimpleNamespace

    from hostd.control import Control

    printer = _FakePrinter()
    loop = Control(node.config, node.store, [SimpleNamespace(name="sim", printer=printer,
                                                             paused=False,
                                                             job_id=node.printing)])
    node.store.request("estop", "sim")
    node.store.request("reorder", json.dumps([node.queued2]))
    node.store.request("estop", "nope")
    loop.answer()
    rows = node.store.db.execute("SELECT action, ok, result FROM control ORDER BY id").fetchall()
    assert [(r[0], r[1]) for r in rows] == [("estop", 1), ("reorder", 1), ("estop", 0)]
    assert printer.estops == 1 and loop.slots[0].paused is True
    assert node.store.printers()["sim"]["paused"] == 1
    assert node.store.events(node.printing)[-1]["kind"] == "estop"
    order = [j["id"] for j in node.store.next_in_order(J.QUEUED)]
    assert order == [node.queued2, node.queued]


def test_an_action_on_a_full_job_database_is_refused_with_the_reason(node):
    from daemon_helpers import fill_store
    fill_store(node.app.config["HOSTD_VIEW"].store)   # the connection this thread's requests use
    r = node.client.post("/api/jobs/%s/cancel" % node.queued, headers=node.auth())
    assert r.status_code == 503 and r.json["code"] == "jobs.disk_full"
    assert "cannot record jobs" in r.json["error"] and "Fix: free space" in r.json["error"]
    page = node.client.post("/actions/jobs/%s/cancel" % node.queued,
                            data={"token": TOKEN, "confirm": "yes"})
    assert page.status_code == 503 and "cannot record jobs" in page.get_data(as_text=True)
    node.store.close()


def test_the_job_card_states_the_shape_against_the_file_and_against_the_plan(node):
    out = node.config.outbox_dir / node.printing
    (out / "dome.report.json").write_text(json.dumps({
        "gcode": {"estimated_print_s": 100.0, "filament_mm": 12.5, "lines": 5},
        "simulation": {"mean_displacement_mm": 1.28, "mean_displacement_fraction": 0.0072},
        "gate": {"limits": {"max_mean_displacement": 0.03}},
        "fit": {"applied_smooth_mm": 6.0, "applied_scale": 1.0},
        "fidelity": {"mean_mm": 2.55, "p90_mm": 5.2, "relief_reached": 0.56,
                     "relief_given_mm": 26.3, "right_way_strong": 0.82,
                     "curvature_slope": 0.34, "kept_from_mm": 8.0}}))
    page = node.client.get("/jobs/" + node.printing).get_data(as_text=True)
    assert ("The simulated sheet ends 2.5 mm from the file as dropped on average (9 in 10 "
            "points within 5.2 mm) and reaches 56 % of its 26.3 mm relief") in page
    assert "curve the right way on 82 % of the area, and keep 34 % of their curvature" in page
    assert ("keeps at least 80 % of the height of hills and valleys about 26 mm across and "
            "wider, less of the narrower ones") in page
    assert ("The sheet ends 1.3 mm (0.7 % of the diameter) from the shape it was planned for "
            "(your file smoothed 6 mm); the printability check allows 3.0 % of the diameter"
            ) in page
