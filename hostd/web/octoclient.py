"""What OctoPrint clients read and do beyond the read-only subset: server, settings,
connection, job commands and the SSDP discovery document.

``/api/server`` and ``/api/settings`` (the part clients read: the discovery plugin's
``upnpUuid``, which Home Assistant takes as the node's identity; tracking; a disabled
webcam), ``/api/connection`` (GET the link, POST connect/disconnect), ``POST /api/job``
(start, cancel, pause with OctoPrint's bodies; 204 when done, 409 with ``{"error"}``
when the printer's state does not allow it) and ``/plugin/discovery/discovery.xml``.

Actions go through the same requests as the page's buttons (:mod:`hostd.web.api`). hostd
keeps its printers connected and starts queued jobs itself, so "connect" releases a
printer held by a person and "disconnect" holds it (it takes no new job; its port stays
open so its heaters stay watched); "start" releases a held printer to print its queue.
"""

from xml.sax.saxutils import escape

from flask import Blueprint, Response, jsonify, request

from hostd.announce import node_uuid
from hostd.web import api, octoprint
from hostd.web.appkeys import client_problem, octo_error

bp = Blueprint("octoclient", __name__)
PAUSE_ACTIONS = ("pause", "resume", "toggle")


def _uuid():
    return node_uuid(api.view().config.state_dir)


@bp.get("/api/server")
def server():
    return jsonify(version=octoprint.SERVER_VERSION, safemode=None)


@bp.get("/api/settings")
def settings():
    v = api.view()
    uid = _uuid()
    return jsonify({
        "api": {"allowCrossOrigin": False},
        "appearance": {"name": v.config.node_id},
        "plugins": {
            "discovery": {"upnpUuid": uid, "publicHost": None, "publicPort": None,
                          "pathPrefix": None, "httpUsername": None, "httpPassword": None,
                          "zeroConf": [], "model": {"name": "hostd", "vendor": "hostd"}},
            "tracking": {"enabled": False, "unique_id": uid},
        },
        "webcam": {"webcamEnabled": False, "timelapseEnabled": False, "streamUrl": "",
                   "snapshotUrl": "", "snapshotSslValidation": True, "flipH": False,
                   "flipV": False, "rotate90": False, "bitrate": ""},
    })


def _printer_or_404():
    p = octoprint._printer()
    if p is None:
        return None, octo_error(404, "no such printer on this node; ?printer=NAME picks one "
                                     "of: %s" % ", ".join(c.name for c in
                                                          api.view().config.printers))
    return p, None


def _client_printer():
    """The printer an OctoPrint client's action is for, or the answer that refuses it
    (no key or token, or no such printer): (printer, None) or (None, response)."""
    problem = client_problem()
    if problem:
        return None, problem
    return _printer_or_404()


@bp.get("/api/connection")
def connection():
    p, missing = _printer_or_404()
    if missing:
        return missing
    cfg = api.view().config.printer(p["name"])
    state = "Closed" if p["state"] == "disconnected" else octoprint.state_text(p)
    return jsonify({
        "current": {"state": state, "port": cfg.port, "baudrate": cfg.baud,
                    "printerProfile": cfg.profile},
        "options": {"ports": [c.port for c in api.view().config.printers],
                    "baudrates": sorted({c.baud for c in api.view().config.printers}),
                    "printerProfiles": [{"id": c.profile, "name": c.profile}
                                        for c in api.view().config.printers],
                    "portPreference": cfg.port, "baudratePreference": cfg.baud,
                    "printerProfilePreference": cfg.profile, "autoconnect": True},
    })


def _done(result):
    """An action's (status, body) as OctoPrint answers it: 204, or the error."""
    status, body = result
    if status < 300 and body.get("ok"):
        return "", 204
    if status == 202:                 # recorded; the run loop has not answered yet
        resp = jsonify(body)
        resp.status_code = 202
        return resp
    return octo_error(409 if status < 500 else status,
                      body.get("error") or body.get("message") or "not done")


@bp.post("/api/connection")
def connection_command():
    p, refused = _client_printer()
    if refused:
        return refused
    command = (request.get_json(silent=True) or {}).get("command")
    if command == "connect":
        if not p["paused"] and p["state"] != "error":
            return "", 204            # hostd keeps it connected (and reconnects it) already
        return _done(api.printer_action(p["name"], "resume"))
    if command == "disconnect":
        if p["job"]:
            return octo_error(409, "printer %s is printing %s: cancel the job first"
                              % (p["name"], p["job"]["name"]))
        if p["paused"]:
            return "", 204
        return _done(api.printer_action(p["name"], "pause"))
    if command == "fake_ack":
        return "", 204                # hostd's link never misses an ok: nothing to fake
    return octo_error(400, "unknown command %r; use connect, disconnect or fake_ack" % command)


@bp.post("/api/job")
def job_command():
    p, refused = _client_printer()
    if refused:
        return refused
    body = request.get_json(silent=True) or {}
    command = body.get("command")
    job = p["job"]
    if command == "start":
        if job:
            return octo_error(409, "Printer is already printing")
        if not p["paused"]:
            return octo_error(409, "nothing to start on %s: hostd starts queued jobs by "
                                   "itself when the printer is free (upload a file to queue "
                                   "one)" % p["name"])
        return _done(api.printer_action(p["name"], "resume"))
    if command == "cancel":
        if not job:
            return octo_error(409, "Printer is neither printing nor paused")
        return _done(api.job_action(job["id"], "cancel"))
    if command == "pause":
        action = body.get("action", "toggle")
        if action not in PAUSE_ACTIONS:
            return octo_error(400, "action must be one of " + ", ".join(PAUSE_ACTIONS))
        if not job:
            return octo_error(409, "Printer is neither printing nor paused")
        paused = octoprint.state_text(p) == "Paused"
        if action == "toggle":
            action = "resume" if paused else "pause"
        if (action == "pause") == paused:
            return "", 204            # already as asked, as OctoPrint answers
        return _done(api.job_action(job["id"], action))
    if command == "restart":
        return octo_error(409, "hostd does not restart a print from its start: cancel it and "
                               "requeue the job")
    return octo_error(400, "unknown command %r; use start, cancel or pause" % command)


@bp.get("/plugin/discovery/discovery.xml")
def discovery_xml():
    v = api.view()
    base = request.host_url
    name = escape("hostd node %s" % v.config.node_id)
    xml = """<?xml version="1.0"?>
<root xmlns="urn:schemas-upnp-org:device-1-0">
  <specVersion><major>1</major><minor>0</minor></specVersion>
  <URLBase>%(base)s</URLBase>
  <device>
    <deviceType>urn:schemas-upnp-org:device:Basic:1</deviceType>
    <friendlyName>%(name)s</friendlyName>
    <manufacturer>hostd</manufacturer>
    <modelDescription>4D printing host with OctoPrint's API %(api)s</modelDescription>
    <modelName>hostd</modelName>
    <modelNumber>%(version)s</modelNumber>
    <serialNumber>%(uuid)s</serialNumber>
    <UDN>uuid:%(uuid)s</UDN>
    <presentationURL>%(base)s</presentationURL>
  </device>
</root>
""" % dict(base=escape(base), name=name, api=octoprint.API_VERSION,
           version=octoprint.SERVER_VERSION, uuid=_uuid())
    return Response(xml, mimetype="text/xml")
