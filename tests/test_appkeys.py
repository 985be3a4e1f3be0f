"""Application keys: the store, the plugin's endpoints, the page, the command, and what a key
may and may not do."""

import json
import sqlite3

import pytest

from hostd.appkeys import FILE, PENDING_S, KeyStore
from hostd.cli import main as cli
from test_web_api import TOKEN, Node, answerer, node  # noqa: F401 (fixtures)


def ask(client, app="Home Assistant"):
    r = client.post("/plugin/appkeys/request", json={"app": app, "user": "admin"})
    assert r.status_code == 201, r.json
    assert r.headers["Location"].endswith("/plugin/appkeys/request/" + r.json["app_token"])
    return r.json["app_token"]


def approved_key(node, app="Home Assistant"):
    app_token = ask(node.client, app)
    pending = node.client.get("/api/appkeys", headers=node.auth()).json["pending"]
    rid = next(p["id"] for p in pending if p["app"] == app)
    r = node.client.post("/api/appkeys/%s/approve" % rid, headers=node.auth())
    assert r.status_code == 200, r.json
    r = node.client.get("/plugin/appkeys/request/" + app_token)
    assert r.status_code == 200
    return r.json["api_key"]


def test_store_request_approve_collect_once_and_kept_hashed(tmp_path):
    ks = KeyStore(tmp_path)
    app_token = ks.request("Home Assistant", "admin", "10.0.0.5")
    assert ks.poll(app_token) == "pending"
    [req] = ks.pending()
    assert (req["app"], req["user"], req["remote"]) == ("Home Assistant", "admin", "10.0.0.5")
    assert ks.check("anything") is None
    assert "approved" in ks.approve(req["id"])
    key = ks.poll(app_token)
    assert len(key) == 32 and ks.check(key) == "Home Assistant"
    assert ks.poll(app_token) is None            # collected once, then the request is gone
    raw = (tmp_path / FILE).read_bytes()
    for secret in (key, app_token):
        assert secret.encode() not in raw
    assert ks.keys()[0]["last_used"] is not None
    assert set(ks.keys()[0]) == {"id", "app", "created", "last_used", "remote"}


def test_store_deny_expire_revoke_and_one_key_per_app(tmp_path):
    ks = KeyStore(tmp_path)
    denied = ks.request("dash")
    ks.deny(ks.pending()[0]["id"])
    assert ks.poll(denied) is None
    old = ks.request("dash", now=1000.0)
    assert ks.poll(old, now=1000.0 + PENDING_S + 1) is None       # expired
    first, second = ks.request("dash"), ks.request("dash")
    for rid in [p["id"] for p in ks.pending()]:
        ks.approve(rid)
    k1, k2 = ks.poll(first), ks.poll(second)
    assert ks.check(k1) is None and ks.check(k2) == "dash"        # the newer replaced it
    assert len(ks.keys()) == 1
    assert "revoked" in ks.revoke("dash")
    assert ks.check(k2) is None
    with pytest.raises(Exception) as exc:
        ks.revoke("dash")
    assert exc.value.code == "appkeys.unknown"
    with pytest.raises(Exception) as exc:
        ks.approve("nope")
    assert exc.value.code == "appkeys.no_request"


def test_an_approved_key_nobody_collects_expires_with_its_request(tmp_path):
    ks = KeyStore(tmp_path)
    app_token = ks.request("dash", now=1000.0)
    ks.approve(ks.pending(now=1000.0)[0]["id"], now=1000.0)
    assert len(ks.keys()) == 1
    ks.pending(now=1000.0 + PENDING_S + 1)
    assert ks.keys() == [] and ks.poll(app_token) is None


def test_plugin_flow_pending_approved_denied(node):
    assert node.client.get("/plugin/appkeys/probe").status_code == 204
    app_token = ask(node.client)
    r = node.client.get("/plugin/appkeys/request/" + app_token)
    assert r.status_code == 202 and r.json == {}
    rid = node.client.get("/api/appkeys", headers=node.auth()).json["pending"][0]["id"]
    assert node.client.post("/api/appkeys/%s/deny" % rid, headers=node.auth()).status_code == 200
    r = node.client.get("/plugin/appkeys/request/" + app_token)
    assert r.status_code == 404 and "denied" in r.json["error"]
    key = approved_key(node)
    assert node.client.get("/api/printer", headers={"X-Api-Key": key}).status_code == 200


def test_bad_requests_are_refused_clearly(node):
    r = node.client.post("/plugin/appkeys/request", json={})
    assert r.status_code == 400 and r.json["code"] == "appkeys.bad_app"
    r = node.client.post("/plugin/appkeys/request", json={"app": "x\x1b[2J"})
    assert r.status_code == 400
    for i in range(20):
        ask(node.client, "app%d" % i)
    r = node.client.post("/plugin/appkeys/request", json={"app": "one more"})
    assert r.status_code == 429 and r.json["code"] == "appkeys.too_many"


def test_keys_are_off_without_a_token(tmp_path):
    n = Node(tmp_path, token=None)
    r = n.client.get("/plugin/appkeys/probe")
    assert r.status_code == 404 and r.json["code"] == "appkeys.off"
    assert n.client.post("/plugin/appkeys/request", json={"app": "x"}).status_code == 403
    r = n.client.post("/api/job", json={"command": "cancel"}, headers={"X-Api-Key": "k" * 32})
    assert r.status_code == 403
    n.store.close()


ACTIONS = [("/api/job", {"json": {"command": "cancel"}}),
           ("/api/job", {"json": {"command": "pause", "action": "pause"}}),
           ("/api/job", {"json": {"command": "start"}}),
           ("/api/connection", {"json": {"command": "disconnect"}}),
           ("/api/connection", {"json": {"command": "connect"}}),
           ("/api/files/local", {"data": {"file": (b"\x93NUMPY", "a.npy")}}),
           ("/api/appkeys/x/approve", {}), ("/api/appkeys/x/deny", {}),
           ("/api/appkeys/x/revoke", {})]


def _body(kw):
    import io
    if "data" in kw:
        content, name = kw["data"]["file"]
        return {"data": {"file": (io.BytesIO(content), name)}}
    return kw


@pytest.mark.parametrize("url,kw", ACTIONS)
def test_no_action_without_a_key_or_the_token(node, url, kw):
    for headers in ({}, {"X-Api-Key": "not-a-key"}, {"Authorization": "Bearer wrong"}):
        r = node.client.post(url, headers=headers, **_body(kw))
        assert r.status_code in (401, 403), (url, headers, r.status_code)
        assert "error" in r.json
    assert node.store.pending_requests() == []
    assert list(node.config.drop_dir.iterdir()) == []


def test_a_key_does_only_what_octoprint_clients_do(node, answerer):
    key = approved_key(node)
    h = {"X-Api-Key": key}
    # hostd's own actions stay the token's
    assert node.client.post("/api/jobs/%s/cancel" % node.queued, headers=h).status_code == 401
    assert node.client.post("/api/printers/sim/estop", headers=h).status_code == 401
    assert node.client.post("/api/appkeys/x/revoke", headers=h).status_code == 401
    assert answerer.seen == []
    r = node.client.post("/api/job", headers=h, json={"command": "pause", "action": "pause"})
    assert r.status_code == 204
    r = node.client.post("/api/job", headers=h, json={"command": "cancel"})
    assert r.status_code == 204
    assert answerer.seen == [("pause", "sim"), ("cancel", node.printing)]


def test_wrong_or_revoked_keys_get_octoprints_403(node):
    key = approved_key(node)
    # One character changed (a key may end in "x" already: then it would be the key).
    wrong = key[:-1] + ("y" if key.endswith("x") else "x")
    for url in ("/api/printer", "/api/job", "/api/version", "/api/settings", "/api/status"):
        r = node.client.get(url, headers={"X-Api-Key": wrong})
        assert r.status_code == 403 and r.json["error"] == "Invalid API key", url
        assert node.client.get(url, headers={"X-Api-Key": key}).status_code == 200
    kid = node.client.get("/api/appkeys", headers=node.auth()).json["keys"][0]["id"]
    assert node.client.post("/api/appkeys/%s/revoke" % kid, headers=node.auth()).status_code == 200
    r = node.client.get("/api/printer", headers={"X-Api-Key": key})
    assert r.status_code == 403 and r.json == {"error": "Invalid API key", "code": "appkeys.invalid"}


def test_page_shows_requests_and_keys_never_the_key(node):
    ask(node.client, "Farm <dash>")
    page = node.client.get("/").get_data(as_text=True)
    assert "Farm &lt;dash&gt;" in page and "127.0.0.1" in page and 'id="appkeys"' in page
    rid = node.client.get("/api/appkeys", headers=node.auth()).json["pending"][0]["id"]
    # approving from the page needs the token and the confirmation box
    r = node.client.post("/actions/appkeys/%s/approve" % rid, data={"token": "wrong",
                                                                    "confirm": "yes"})
    assert r.status_code == 401
    r = node.client.post("/actions/appkeys/%s/approve" % rid, data={"token": TOKEN})
    assert r.status_code == 400
    r = node.client.post("/actions/appkeys/%s/approve" % rid, data={"token": TOKEN,
                                                                    "confirm": "yes"})
    assert r.status_code == 200
    key = approved_key(node, "other")
    page = node.client.get("/").get_data(as_text=True)
    assert key not in page and "Revoke" in page and "Farm &lt;dash&gt;" in page
    assert key not in json.dumps(node.client.get("/api/appkeys", headers=node.auth()).json)


def test_command_lists_approves_denies_and_revokes(tmp_path, capsys):
    from daemon_helpers import write_config
    config = write_config(tmp_path, web={"host": "127.0.0.1", "port": 0, "token": TOKEN})
    from hostd.config import load_config
    ks = KeyStore(load_config(config).state_dir)
    ha, dash = ks.request("Home Assistant", remote="10.0.0.5"), ks.request("dash")
    assert cli(["keys", "list", "-c", str(config)]) == 0
    out = capsys.readouterr().out
    assert "Home Assistant" in out and "10.0.0.5" in out
    assert cli(["keys", "list", "--json", "-c", str(config)]) == 0
    pending = json.loads(capsys.readouterr().out)["pending"]
    ids = {p["app"]: p["id"] for p in pending}
    assert cli(["keys", "approve", ids["Home Assistant"], "-c", str(config)]) == 0
    assert cli(["keys", "deny", ids["dash"], "-c", str(config)]) == 0
    key = ks.poll(ha)
    assert ks.check(key) == "Home Assistant" and ks.poll(dash) is None
    capsys.readouterr()
    assert cli(["keys", "approve", "nope", "-c", str(config)]) == 2
    assert "appkeys.no_request" in capsys.readouterr().err
    assert cli(["keys", "revoke", "Home Assistant", "-c", str(config)]) == 0
    assert ks.check(key) is None
    assert key not in capsys.readouterr().out


def test_command_refuses_without_a_token(tmp_path, capsys):
    from daemon_helpers import write_config
    config = write_config(tmp_path)
    assert cli(["keys", "list", "-c", str(config)]) == 2
    assert "appkeys.off" in capsys.readouterr().err


def test_store_file_is_private(tmp_path):
    KeyStore(tmp_path)
    assert (tmp_path / FILE).stat().st_mode & 0o077 == 0
    db = sqlite3.connect(tmp_path / FILE)
    assert {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")} \
        == {"requests", "keys"}


def test_the_page_needs_no_key_store_and_survives_a_broken_one(tmp_path):
    n = Node(tmp_path)
    page = n.client.get("/")
    assert page.status_code == 200 and 'id="appkeys"' in page.get_data(as_text=True)
    assert not (n.config.state_dir / FILE).exists()       # a page view creates nothing
    (n.config.state_dir / FILE).mkdir()                    # unreadable as a database
    assert n.client.get("/").status_code == 200
    r = n.client.get("/api/printer", headers={"X-Api-Key": "k" * 32})
    assert r.status_code == 503 and r.json["code"] == "appkeys.store"
    n.store.close()


def test_node_uuid_without_a_writable_state_folder_is_still_stable(tmp_path):
    from hostd.announce import node_uuid
    blocker = tmp_path / "state"
    blocker.write_text("a file where the folder should be")
    first = node_uuid(blocker / "sub")
    assert first == node_uuid(blocker / "sub") and len(first) == 36
    assert node_uuid(tmp_path / "ok") == node_uuid(tmp_path / "ok") != first
