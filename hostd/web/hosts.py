"""Which Host header names the page and API answer to (a guard against DNS rebinding).

A web page from anywhere can make the browser fetch ``http://evil.example:8080/api/status``
after pointing that name at 127.0.0.1 or at a node on the LAN: the browser then treats our
answer as the stranger's own and lets its script read it. Such a request carries the
stranger's name in its Host header, so we answer only to names we know: localhost names,
any IP address (a name nobody's DNS can re-point), this machine's host name (the farm view
links to it), ``web.host``, and ``web.allowed_hosts`` from hostd.yaml. An entry starting
with a dot allows that domain and its subdomains; ``*`` allows every name (behind a reverse
proxy that checks them itself).

Wrapped around the WSGI app, so every route -- page, API, OctoPrint subset, /metrics,
/healthz -- is covered without each one asking.
"""

import ipaddress
import json
import socket

LOCAL = ("localhost", "localhost.localdomain", "ip6-localhost", "ip6-loopback")


def host_name(header):
    """The name in a Host header without its port: ``"[::1]:80"`` -> ``"::1"``; lower case."""
    header = header.strip().lower()
    if header.startswith("["):
        return header[1:header.find("]")] if "]" in header else header
    if header.count(":") == 1:
        header = header.split(":", 1)[0]
    return header.rstrip(".")


def is_ip(name):
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return False


class Names:
    """The names one node answers to (see module docstring)."""

    def __init__(self, web_config, hostname=None):
        hostname = (hostname or socket.gethostname()).lower()
        short = hostname.split(".")[0]
        names = set(LOCAL) | {hostname, short, short + ".local"}
        names.add(host_name(web_config.host or ""))
        names.update(n.strip().lower().rstrip(".") for n in web_config.allowed_hosts)
        self.any = "*" in names
        self.domains = tuple(n for n in names if n.startswith(".") and len(n) > 1)
        self.names = frozenset(n for n in names if n and not n.startswith("."))

    def allows(self, header):
        if self.any or header is None:        # HTTP/1.0 without Host: no browser sends that
            return True
        name = host_name(header)
        if name in self.names or is_ip(name) or name.endswith(".localhost"):
            return True
        return any(name.endswith(d) or name == d[1:] for d in self.domains)


class HostGuard:
    """WSGI middleware answering 421 to a request for a name this node does not go by."""

    def __init__(self, app, names):
        self.app = app
        self.names = names

    def __call__(self, environ, start_response):
        header = environ.get("HTTP_HOST")
        if self.names.allows(header):
            return self.app(environ, start_response)
        name = host_name(header)[:100]
        message = ("this node does not answer to the name %r; if it is one of its own, add it to "
                   "web.allowed_hosts in hostd.yaml and restart hostd" % name)
        if environ.get("PATH_INFO", "").startswith("/api/"):
            body = json.dumps({"ok": False, "error": message, "code": "web.host"}).encode()
            kind = "application/json"
        else:
            body = ("Misdirected request: %s.\n" % message).encode()
            kind = "text/plain; charset=utf-8"
        start_response("421 Misdirected Request", [("Content-Type", kind),
                                                   ("Content-Length", str(len(body)))])
        return [body]
