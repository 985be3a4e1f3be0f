"""Clients sending their request heads slowly cannot lock people out of the page: a head
must arrive whole in bounded time, and connections waiting longest for a request of their
own make room for new ones. Real sockets on 127.0.0.1, bounded in count and time."""

import dataclasses
import socket
import threading
import time

from hostd.web import server
from test_web_api import TOKEN, Node
from web_helpers import get_json


def _serve(node, monkeypatch, **limits):
    for name, value in limits.items():
        monkeypatch.setattr(server, name, value, raising=False)
    config = dataclasses.replace(node.config, web=dataclasses.replace(node.config.web, port=0))
    web = server.start(config, store=node.store)
    return web, int(web.url.rsplit(":", 1)[1].rstrip("/"))


def _closed_by_server(sock, within_s):
    """True once the server closes ``sock`` (a header line sent every 0.2 s meanwhile)."""
    deadline = time.monotonic() + within_s
    sock.settimeout(0.2)
    n = 0
    while time.monotonic() < deadline:
        try:
            sock.sendall(b"X-Slow-%d: 1\r\n" % n)
            n += 1
            if sock.recv(4096) == b"":
                return True
        except socket.timeout:
            continue
        except OSError:
            return True
    return False


def test_a_head_that_keeps_trickling_is_cut_off(tmp_path, monkeypatch):
    node = Node(tmp_path)
    web, port = _serve(node, monkeypatch, HEAD_TIMEOUT_S=1.5)
    try:
        sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        sock.sendall(b"GET / HTTP/1.1\r\nHost: localhost\r\n")
        # Never idle for the 30 s channel timeout, but the head never ends.
        assert _closed_by_server(sock, within_s=10)
        sock.close()
        # A whole head is served as ever, and a slow body is not a slow head.
        sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: localhost\r\n\r\n")
        assert sock.recv(4096).startswith(b"HTTP/1.1 200")
        sock.close()
    finally:
        web.stop()
        node.store.close()


class Tricklers:
    """``count`` connections each sending one more header line every ``every_s``; one the
    server closes is opened again (an attacker keeps trying), up to ``max_opened``."""

    def __init__(self, port, count, every_s=0.5, max_opened=2000):
        self.port, self.every_s, self.max_opened = port, every_s, max_opened
        self.socks = [self._open() for _ in range(count)]
        self.opened = count
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _open(self):
        s = socket.create_connection(("127.0.0.1", self.port), timeout=5)
        s.setblocking(False)
        s.sendall(b"GET / HTTP/1.1\r\nHost: localhost\r\n")
        return s

    def _run(self):
        n = 0
        while not self.stop.wait(self.every_s):
            n += 1
            for i, s in enumerate(self.socks):
                try:
                    s.send(b"X-Slow-%d: 1\r\n" % n)
                except BlockingIOError:
                    pass
                except OSError:
                    s.close()
                    if self.opened < self.max_opened:
                        try:
                            self.socks[i] = self._open()
                            self.opened += 1
                        except OSError:
                            pass

    def close(self):
        self.stop.set()
        self.thread.join(10)
        for s in self.socks:
            s.close()


def test_the_page_healthz_and_estop_answer_while_connections_trickle_headers(tmp_path,
                                                                           monkeypatch):
    node = Node(tmp_path)
    # More trickling connections than the server keeps at all; heads never time out here.
    web, port = _serve(node, monkeypatch, CONNECTION_LIMIT=60, WAITING_LIMIT=40,
                       HEAD_TIMEOUT_S=300.0)
    crowd = None
    try:
        crowd = Tricklers(port, 80)
        time.sleep(1.0)
        base = "http://127.0.0.1:%d/" % port
        for _ in range(3):
            status, body = get_json(base + "healthz", timeout=10)
            assert status == 200 and body["ok"] is True
            status, body = get_json(base + "api/status", timeout=10)
            assert status == 200 and body["node_id"] == "n1"
            # The page's emergency stop reaches the app (no daemon here: refused, answered).
            status, body = get_json(base + "api/printers/p1/estop", timeout=10, method="POST",
                                    headers={"Authorization": "Bearer " + TOKEN})
            assert status in (200, 404, 409, 503) and "error" in body or body.get("ok")
    finally:
        if crowd is not None:
            crowd.close()
        web.stop()
        node.store.close()
