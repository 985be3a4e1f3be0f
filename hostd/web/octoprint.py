"""A read-only subset of OctoPrint's REST API: ``/api/version``, ``/api/job``, ``/api/printer``.

Same field names, types and meanings as OctoPrint's, so farm dashboards and home-automation
integrations that poll OctoPrint can watch a hostd node unchanged. OctoPrint drives one
printer; a hostd node may have several: ``?printer=NAME`` picks one (default: the first).
Reads are public; an ``X-Api-Key`` those clients send must be an approved application key
(:mod:`hostd.web.appkeys`), which also lets them act (:mod:`hostd.web.octoclient`).
"""

from flask import Blueprint, jsonify, request

from hostd.web.api import error, view

bp = Blueprint("octoprint", __name__)

API_VERSION = "0.1"
SERVER_VERSION = "1.10.0"      # the OctoPrint release whose API this subset follows

# page state -> OctoPrint's state text
STATE_TEXT = {"idle": "Operational", "heating": "Printing", "printing": "Printing",
              "paused": "Paused", "error": "Error", "disconnected": "Offline"}
_HEATERS = {"T": "tool0", "B": "bed", "C": "chamber"}


def _printer():
    printers = view().printers()
    name = request.args.get("printer")
    if name:
        printers = [p for p in printers if p["name"] == name]
    return printers[0] if printers else None


def heater_name(heater):
    """Marlin report key (``T``, ``T0``, ``T1``, ``B``, ``C``) -> OctoPrint's (``tool0``, ``bed``)."""
    if heater in _HEATERS:
        return _HEATERS[heater]
    if heater.startswith("T") and heater[1:].isdigit():
        return "tool%d" % int(heater[1:])
    return heater.lower()


def state_text(p):
    if p["state"] == "paused" and not p["job"]:
        return "Operational"          # operator hold without a job: idle for OctoPrint
    return STATE_TEXT.get(p["state"], "Offline")


def state_flags(p):
    text = state_text(p)
    printing = text == "Printing"
    paused = text == "Paused"
    error_ = text == "Error"
    closed = text in ("Offline", "Error")
    return {"operational": not closed, "printing": printing, "paused": paused,
            "pausing": False, "cancelling": False, "sdReady": False, "error": error_,
            "ready": not closed and not printing and not paused, "closedOrError": closed}


@bp.get("/api/version")
def version():
    from hostd import __version__
    return jsonify(api=API_VERSION, server=SERVER_VERSION,
                   text="OctoPrint %s (hostd %s)" % (SERVER_VERSION, __version__))


@bp.get("/api/printer")
def printer():
    p = _printer()
    if p is None:
        return error(404, "no such printer")
    if p["state"] in ("disconnected",):
        return error(409, "Printer is not operational")
    temps = {}
    for heater, t in p["temperatures"].items():
        key = heater_name(heater)
        if key not in temps or heater in ("T", "B", "C"):
            temps[key] = {"actual": t["current"], "target": t["target"], "offset": 0}
    out = {"temperature": temps, "sd": {"ready": False},
           "state": {"text": state_text(p), "flags": state_flags(p)}}
    exclude = set((request.args.get("exclude") or "").split(","))
    return jsonify({k: v for k, v in out.items() if k not in exclude})


@bp.get("/api/job")
def job():
    p = _printer()
    if p is None:
        return error(404, "no such printer")
    job = p["job"]
    file_ = {"name": None, "display": None, "path": None, "origin": None, "size": None,
             "date": None}
    progress = {"completion": None, "filepos": None, "printTime": None, "printTimeLeft": None,
                "printTimeLeftOrigin": None}
    estimated, filament = None, None
    if job:
        v = view()
        row = v.job(job["id"])
        gcode = next((f for f in job["files"] if f.endswith(".gcode")), None)
        size = date = None
        st = v.outbox_stat(row, gcode) if gcode and row else None
        if st is not None:
            size, date = st.st_size, int(st.st_mtime)
        file_ = {"name": gcode or job["name"], "display": job["name"], "path": gcode,
                 "origin": "local", "size": size, "date": date}
        report = v.report(row) if row else None
        g = (report or {}).get("gcode") or {}
        estimated = g.get("estimated_print_s")
        if g.get("filament_mm") is not None:
            filament = {"tool0": {"length": g["filament_mm"], "volume": None}}
        frac = job["progress"] or 0.0
        progress = {"completion": round(100.0 * frac, 2),
                    "filepos": int(size * frac) if size else None,
                    "printTime": int(job["elapsed_s"]) if job["elapsed_s"] is not None else None,
                    "printTimeLeft": int(job["eta_s"]) if job["eta_s"] is not None else None,
                    "printTimeLeftOrigin": "linear" if job["eta_s"] is not None else None}
    return jsonify({"job": {"file": file_, "estimatedPrintTime": estimated,
                            "lastPrintTime": None, "filament": filament, "user": None},
                    "progress": progress, "state": state_text(p)})
