"""How OctoPrint clients find a node: its UPnP uuid and its zeroconf announcement.

The uuid is drawn once and kept in ``STATE/upnp_uuid``: Home Assistant takes a node's
identity from it, so it must survive restarts and moves of the page to another port.

The announcement (``_octoprint._tcp`` and ``_http._tcp``, with the TXT keys OctoPrint's
discovery plugin sends) goes out where the page listens: on every interface when it listens
on all (``0.0.0.0``), on that address's interface otherwise. ``web.announce`` null (the
default) announces only when the page listens beyond localhost, where nobody else could
reach it; true announces wherever it listens (on loopback too: tests, one machine), false
never.
"""

import ipaddress
import logging
import socket
import uuid
from pathlib import Path

log = logging.getLogger("hostd.web")

UUID_FILE = "upnp_uuid"
SERVICES = ("_octoprint._tcp.local.", "_http._tcp.local.")


def node_uuid(state_dir):
    """This node's UPnP uuid (text), drawn at first use and kept in the state folder."""
    path = Path(state_dir) / UUID_FILE
    try:
        return str(uuid.UUID(path.read_text().strip()))
    except (OSError, ValueError):
        pass
    value = str(uuid.uuid4())
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        part = path.with_name(path.name + ".part")
        part.write_text(value + "\n")
        part.replace(path)
    except OSError as exc:
        # A full state folder must not take the API down: a uuid of the folder's path,
        # the same at every try until the file can be written.
        log.warning("cannot keep this node's uuid in %s (%s); using one derived from the "
                    "folder's path until it can be written", path, exc.strerror)
        return str(uuid.uuid5(uuid.NAMESPACE_URL, "hostd:" + str(path.resolve())))
    return value


def _loopback(host):
    if host in ("localhost", ""):
        return host == "localhost"
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def wanted(web):
    """Whether ``web`` (a WebConfig) asks for an announcement."""
    if web.announce is not None:
        return bool(web.announce)
    return not _loopback(web.host)


def _addresses(host):
    """(zeroconf interfaces, IPv4 addresses to announce) for a page listening on ``host``."""
    if host in ("0.0.0.0", "::", ""):
        import ifaddr
        found = [ip.ip for a in ifaddr.get_adapters() for ip in a.ips
                 if isinstance(ip.ip, str) and not ipaddress.ip_address(ip.ip).is_loopback]
        return None, found
    if host == "localhost":
        host = "127.0.0.1"
    return [host], [host]


def start(config, port):
    """Announce the page at ``port``; the running Zeroconf (close it to withdraw), or None
    when not wanted or when it cannot be announced (logged: the page works without it)."""
    if not wanted(config.web):
        return None
    try:
        return _register(config, port)
    except Exception as exc:     # no multicast route, a missing library: the page still serves
        log.warning("the node is not announced on the network (zeroconf: %s); clients can "
                    "still be pointed at its address", exc)
        return None


def _register(config, port):
    from zeroconf import IPVersion, InterfaceChoice, ServiceInfo, Zeroconf

    from hostd.web.octoprint import API_VERSION, SERVER_VERSION
    interfaces, addresses = _addresses(config.web.host)
    zc = Zeroconf(interfaces=interfaces or InterfaceChoice.All, ip_version=IPVersion.V4Only)
    host = socket.gethostname().split(".")[0] or config.node_id
    txt = {"path": "/", "api": API_VERSION, "version": SERVER_VERSION,
           "uuid": node_uuid(config.state_dir), "model": "hostd", "vendor": "hostd"}
    try:
        for service in SERVICES:
            info = ServiceInfo(service, "hostd %s.%s" % (config.node_id, service),
                               addresses=[socket.inet_aton(a) for a in addresses], port=port,
                               properties=txt if service.startswith("_octoprint") else
                               {"path": "/"}, server="%s.local." % host)
            zc.register_service(info, allow_name_change=True)
    except Exception:
        zc.close()
        raise
    log.info("announced as %s on %s (zeroconf)", " and ".join(s[:-7] for s in SERVICES),
             ", ".join(addresses) or "no address")
    return zc
