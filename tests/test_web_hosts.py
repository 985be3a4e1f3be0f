"""The page and API answer only to names this node goes by: a stranger's DNS name pointed at
a node (DNS rebinding) gets 421 on every route, whatever blueprint serves it."""

import dataclasses
import http.client
import os

import pytest

from hostd.config import HostdError, WebConfig, default_data, parse_config
from hostd.web import server
from hostd.web.app import create_app
from hostd.web.hosts import Names, host_name
from test_web_api import Node
from web_helpers import CHROMIUM, Chromium

ROUTES = ["/", "/healthz", "/api/status", "/api/printers", "/api/jobs", "/metrics", "/farm",
          "/api/version", "/api/printer", "/api/job"]


def _client(node, **web):
    config = dataclasses.replace(node.config, web=dataclasses.replace(node.config.web, **web))
    return create_app(config, store=node.store).test_client()


def test_a_strangers_name_is_refused_on_every_route(tmp_path):
    client = _client(Node(tmp_path))
    for path in ROUTES:
        r = client.get(path, headers={"Host": "rebind.attacker.example:8080"})
        assert r.status_code == 421, path
        assert b"web.allowed_hosts" in r.data
    r = client.post("/api/printers/p1/estop", headers={"Host": "rebind.attacker.example"})
    assert r.status_code == 421 and r.get_json()["code"] == "web.host"


def test_local_names_addresses_and_this_machines_name_are_served(tmp_path):
    client = _client(Node(tmp_path))
    import socket
    short = socket.gethostname().split(".")[0]
    for host in ("localhost", "localhost:8080", "127.0.0.1:8080", "[::1]:8080",
                 "192.168.1.20:8080", "[fe80::1]", short, short + ".local:8080",
                 "node.localhost", "LOCALHOST."):
        assert client.get("/api/status", headers={"Host": host}).status_code == 200, host


def test_configured_names_are_served_and_a_dot_allows_a_domain(tmp_path):
    node = Node(tmp_path)
    client = _client(node, allowed_hosts=("printers.lab.example", ".farm.example"))
    for host in ("printers.lab.example", "Printers.Lab.Example:80", "farm.example",
                 "n3.farm.example:8080"):
        assert client.get("/api/status", headers={"Host": host}).status_code == 200, host
    for host in ("lab.example", "evilfarm.example", "printers.lab.example.evil"):
        assert client.get("/api/status", headers={"Host": host}).status_code == 421, host
    anything = _client(node, allowed_hosts=("*",))
    assert anything.get("/api/status", headers={"Host": "x.example"}).status_code == 200
    listen = _client(node, host="node7.lab")
    assert listen.get("/api/status", headers={"Host": "node7.lab:8080"}).status_code == 200


def test_allowed_hosts_in_hostd_yaml_is_a_list_of_names():
    config = parse_config({"web": {"allowed_hosts": ["printers.lab.example"]}},
                          defaults=default_data())
    assert config.web.allowed_hosts == ("printers.lab.example",)
    assert parse_config({}, defaults=default_data()).web.allowed_hosts == ()
    with pytest.raises(HostdError) as err:
        parse_config({"web": {"allowed_hosts": "printers.lab.example"}}, defaults=default_data())
    assert err.value.code == "config.type" and err.value.key == "web.allowed_hosts"


def test_host_name_parsing():
    assert host_name("[::1]:8080") == "::1"
    assert host_name("Example.ORG.:80") == "example.org"
    assert host_name("fe80::1") == "fe80::1"
    names = Names(WebConfig(host="0.0.0.0"), hostname="pi4.lan")
    assert names.allows("pi4:8080") and names.allows("pi4.lan") and names.allows("pi4.local")
    assert not names.allows("pi4.lan.attacker.example")


def test_the_served_page_refuses_a_strangers_host_header(tmp_path):
    node = Node(tmp_path)
    config = dataclasses.replace(node.config, web=dataclasses.replace(node.config.web, port=0))
    web = server.start(config, store=node.store)
    port = int(web.url.rsplit(":", 1)[1].rstrip("/"))
    try:
        for host, want in (("rebind.attacker.example", 421), ("127.0.0.1:%d" % port, 200)):
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            conn.request("GET", "/api/status", headers={"Host": host})
            r = conn.getresponse()
            r.read()
            conn.close()
            assert r.status == want, host
    finally:
        web.stop()


@pytest.mark.slow
def test_a_rebound_name_in_a_real_browser_reads_nothing(tmp_path):
    """Chromium resolving a stranger's name to this node (as after DNS rebinding) gets the
    refusal, not the node's status."""
    if not os.path.exists(CHROMIUM):
        pytest.skip("Debian's chromium is not installed at %s" % CHROMIUM)
    pytest.importorskip("websocket", reason="pip package websocket-client is not installed")
    node = Node(tmp_path)
    config = dataclasses.replace(node.config, web=dataclasses.replace(node.config.web, port=0))
    web = server.start(config, store=node.store)
    port = int(web.url.rsplit(":", 1)[1].rstrip("/"))
    browser = None
    try:
        browser = Chromium(flags=["--host-resolver-rules=MAP rebind.attacker.example 127.0.0.1"])
        browser.goto("http://rebind.attacker.example:%d/api/status" % port)
        text = browser.js("document.body.innerText")
        assert "web.allowed_hosts" in text and '"node_id"' not in text
        browser.goto("http://127.0.0.1:%d/api/status" % port)
        assert '"node_id"' in browser.js("document.body.innerText")
    finally:
        if browser is not None:
            browser.close()
        web.stop()
