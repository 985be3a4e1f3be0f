"""Helpers for the web tests: a free port, HTTP JSON, and a tiny Chrome DevTools client."""

import base64
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync",
                  "--window-size=1100,1400"]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get_json(url, timeout=5.0, headers=None, method="GET", data=None):
    """(status, body) of a JSON request; never raises on HTTP errors."""
    req = urllib.request.Request(url, headers=headers or {}, method=method, data=data)
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, json.loads(r.read() or b"null")
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b"null")


def wait_http(url, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            return get_json(url, timeout=1.0)
        except (OSError, ValueError):
            time.sleep(0.05)
    raise AssertionError("no answer from %s in %.0f s" % (url, timeout))


class Chromium:
    """Headless Debian chromium driven over the DevTools protocol (one page)."""

    def __init__(self, path=CHROMIUM, flags=()):
        import websocket
        self.profile = tempfile.mkdtemp(prefix="hostd-chromium-")
        port = free_port()
        self.proc = subprocess.Popen([path, *CHROMIUM_FLAGS, *flags,
                                      "--user-data-dir=" + self.profile,
                                      "--remote-debugging-address=127.0.0.1",
                                      "--remote-debugging-port=%d" % port, "about:blank"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        target = None
        while target is None:
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.close()
                raise RuntimeError("chromium did not open its DevTools port")
            try:
                _, pages = get_json("http://127.0.0.1:%d/json/list" % port, timeout=1.0)
                target = next((p for p in pages if p.get("type") == "page"), None)
            except (OSError, ValueError):
                time.sleep(0.05)
        self.ws = websocket.create_connection(target["webSocketDebuggerUrl"], timeout=30,
                                              suppress_origin=True)
        self._id = 0

    def call(self, method, **params):
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise RuntimeError("%s: %s" % (method, msg["error"]))
                return msg.get("result", {})

    def goto(self, url, timeout=20.0):
        self.call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout
        while self.js("document.readyState") != "complete":
            if time.monotonic() > deadline:
                raise AssertionError("page %s did not load" % url)
            time.sleep(0.05)

    def js(self, expression):
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in result:
            raise RuntimeError("JS error in %r: %s" % (expression, result["exceptionDetails"]))
        return result["result"].get("value")

    def wait_js(self, expression, timeout=20.0, what=None):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                value = self.js(expression)
            except RuntimeError:
                value = None
            if value:
                return value
            time.sleep(0.05)
        raise AssertionError("timed out waiting for %s" % (what or expression))

    def screenshot(self, path):
        data = self.call("Page.captureScreenshot", format="png")["data"]
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_bytes(base64.b64decode(data))

    def close(self):
        try:
            if getattr(self, "ws", None) is not None:
                self.ws.close()
        finally:
            if self.proc.poll() is None:
                self.proc.terminate()
                try:
                    self.proc.wait(10)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(5)
            shutil.rmtree(self.profile, ignore_errors=True)


def open_clients(web, request, count, rcvbuf=None):
    """``count`` sockets to the server ``web``, each having sent ``request`` (bytes) and
    reading nothing: clients that are slow, stuck or gone quiet."""
    import socket
    port = int(web.url.rsplit(":", 1)[1].rstrip("/"))
    clients = []
    for _ in range(count):
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
        if rcvbuf:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        s.sendall(request)
        clients.append(s)
    return clients
