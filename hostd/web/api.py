"""The JSON API: ``/api/status``, printers, jobs, files, uploads and token-protected actions.

Actions go through the job store's control table (the terminal commands' door): the
run loop carries them out between two ticks and answers; we wait a few seconds for
that answer. An emergency stop is also written to the port from here at once, when
the daemon runs in this process, so it never waits for a tick.
"""

import hmac
import json
from pathlib import Path

from flask import Blueprint, abort, current_app, jsonify, request, send_file
from werkzeug.wsgi import wrap_file

from hostd import jobs as J
from hostd.errors import HostdError
from hostd.web import uploads
from hostd.watcher import INPUT_SUFFIXES, ignored, name_problem

bp = Blueprint("api", __name__)

NO_TOKEN = ("actions are off on this node: no token is configured. Run `hostd token` in the "
            "folder you start hostd from (it writes ./hostd.yaml), then start it with `hostd run "
            "-c hostd.yaml`; or set `web: {token: SOME-LONG-SECRET}` in the hostd.yaml it runs "
            "with and restart it")
JOB_ACTIONS = ("pause", "resume", "cancel", "requeue", "approve")
# ``clear``: a person says the printer's bed is clear (after every print it waits for one).
PRINTER_ACTIONS = ("estop", "pause", "resume", "clear")


def view():
    return current_app.config["HOSTD_VIEW"]


def error(status, message, **extra):
    resp = jsonify(dict(ok=False, error=message, **extra))
    resp.status_code = status
    return resp


# -- auth ----------------------------------------------------------------------------------

def token_problem(given):
    """None when ``given`` is this node's token, else (status, message)."""
    token = view().config.web.token
    if not token:
        return 403, NO_TOKEN
    if not given or not hmac.compare_digest(given.encode(), token.encode()):
        return 401, "a valid token is required (Authorization: Bearer TOKEN)"
    return None


def bearer():
    header = request.headers.get("Authorization", "")
    return header[7:].strip() if header[:7].lower() == "bearer " else None


def require_token():
    problem = token_problem(bearer())
    if problem:
        resp = error(*problem)
        if problem[0] == 401:
            resp.headers["WWW-Authenticate"] = 'Bearer realm="hostd"'
        abort(resp)


# -- actions (shared with the page's forms) --------------------------------------------------

def ask_daemon(action, target):
    """(http status, body) after the run loop answered the request (202 if not in time)."""
    store = view().store
    req = store.request(action, target)
    answer = store.wait_answer(req, timeout_s=current_app.config["HOSTD_ACTION_WAIT_S"],
                               poll_s=0.02)
    if answer is None:
        return 202, dict(ok=None, request=req, message="%s %s requested; the daemon has not "
                                                       "answered yet" % (action, target))
    ok, result = answer
    return (200, dict(ok=True, result=result)) if ok else (409, dict(ok=False, error=result))


def job_action(job_id, action):
    v = view()
    job = v.job(job_id)
    if job is None:
        return 404, dict(ok=False, error="no job %s" % job_id)
    if action in ("pause", "resume"):
        if job["state"] != J.PRINTING or not job["printer"]:
            return 409, dict(ok=False, error="job %s is %s, not printing" % (job_id, job["state"]))
        return ask_daemon(action, job["printer"])
    if action == "cancel" and job["state"] == J.PRINTING:
        status, body = _printer_first(action, job["id"], lambda slot: slot.job_id == job["id"],
                                      lambda slot: slot.printer.cancel())
        # The printer's cancel above may have ended the print, and the run loop recorded
        # it, before the loop read the request: then the request finds it cancelled.
        if status == 409 and (v.job(job_id) or {}).get("state") == J.CANCELLED:
            return 200, dict(ok=True, result="cancelled %s: the printer ran its cancel script"
                                             % job["id"])
        return status, body
    return ask_daemon(action, job["id"])


def printer_action(name, action):
    v = view()
    if v.config.printer(name) is None:
        return 404, dict(ok=False, error="no printer %s on this node" % name)
    if action == "estop":
        return _printer_first(action, name, lambda slot: slot.name == name, _estop)
    return ask_daemon(action, name)


def _estop(slot):
    slot.printer.estop()              # M112 now
    slot.paused = True                # and nothing new starts there, recorded or not


def _printer_first(action, target, which, act):
    """Cancel and emergency stop act on the printer itself (when the daemon runs in this
    process), then ask the run loop to record them: a full disk, which refuses the
    request, must never stop a person from stopping a print."""
    acted = False
    for slot in getattr(view().daemon, "slots", ()):
        if which(slot) and slot.printer is not None:
            try:
                act(slot)
                acted = True
            except Exception as exc:      # not connected: the run loop says so
                current_app.logger.warning("%s %s: %s", action, target, exc)
    try:
        return ask_daemon(action, target)
    except HostdError as exc:
        if not acted or exc.code != J.DISK_FULL:
            raise
        return 202, dict(ok=True, result="%s %s: sent to the printer; %s, so it is recorded "
                                         "when there is room" % (action, target, exc.message))


def move_in_queue(job_id, where):
    """Reorder: ``where`` is top, up, down, bottom or a 0-based position."""
    ids = [j["id"] for j in view().queue()]
    if job_id not in ids:
        return 409, dict(ok=False, error="job %s is not in the queue" % job_id)
    i = ids.index(job_id)
    ids.pop(i)
    pos = {"top": 0, "up": max(0, i - 1), "down": i + 1, "bottom": len(ids)}.get(where)
    if pos is None:
        try:
            pos = int(where)
        except (TypeError, ValueError):
            return 400, dict(ok=False, error="`to` must be top, up, down, bottom or a number")
    ids.insert(max(0, min(pos, len(ids))), job_id)
    return ask_daemon("reorder", json.dumps(ids))


def _clean_name(raw):
    name = (raw or "").replace("\\", "/").rsplit("/", 1)[-1]
    if not name or name.startswith(".") or name_problem(name):
        return None
    return name


def save_upload(upload, sidecar=None, target=None):
    """Save an uploaded input (and sidecar) into the drop folder, atomically. (status, body)."""
    v = view()
    name = _clean_name(upload.filename if upload else None)
    if not name:
        return 400, dict(ok=False, error="send the file as multipart field `file` with a plain "
                                         "file name (not hidden, no control characters)")
    if Path(name).suffix.lower() not in INPUT_SUFFIXES:
        return 400, dict(ok=False, error="%s: not an input type hostd plans (%s)"
                                         % (name, " ".join(INPUT_SUFFIXES)))
    if ignored(name):
        # The watcher passes over lock files and partial downloads: it would never be a job.
        return 400, dict(ok=False, error="%s: a name the drop folder ignores (lock files "
                                         "~$*, partial downloads, hidden files); rename it"
                                         % name)
    folder = Path(v.config.drop_dir)
    if target:
        known = {p.name for p in v.config.printers} | {p.profile for p in v.config.printers}
        if target not in known:
            return 400, dict(ok=False, error="no printer or profile %s on this node" % target)
        folder = folder / target
    from hostd.web.view import SHARE_HUNG
    saved = v.share_write(uploads.store, folder, name, upload, sidecar,
                          timeout_s=current_app.config.get("HOSTD_SHARE_WRITE_S"))
    if saved is SHARE_HUNG:
        return 503, dict(ok=False, error="the drop folder (%s) does not answer (a network share "
                                         "away?): the upload was not taken; try again once it "
                                         "answers" % v.config.drop_dir)
    if isinstance(saved, OSError):
        return 500, dict(ok=False, error="cannot save the upload: %s" % saved.strerror)
    dest = saved
    rel = dest.relative_to(v.config.drop_dir).as_posix()
    return 201, dict(ok=True, name=dest.name, path=rel,
                     message="%s is in the drop folder; it becomes a job within a few seconds"
                             % rel)


# -- read endpoints -----------------------------------------------------------------------

@bp.get("/healthz")
def healthz():
    v = view()
    v.store.db.execute("SELECT 1").fetchone()
    return jsonify(ok=True, node_id=v.config.node_id, daemon=v.daemon is not None)


@bp.get("/api/status")
def status():
    return jsonify(view().status(history=request.args.get("history") == "1"))


@bp.get("/api/printers")
def printers():
    return jsonify(printers=view().printers(history=request.args.get("history") != "0"))


@bp.get("/api/jobs")
def jobs():
    state = request.args.get("state")
    states = [s for s in state.split(",") if s] if state else None
    if states and any(s not in J.STATES for s in states):
        return error(400, "unknown state; use one of " + ", ".join(J.STATES))
    try:
        limit = max(1, min(1000, int(request.args.get("limit", 200))))
    except ValueError:
        return error(400, "limit must be a number")
    v = view()
    return jsonify(jobs=[v.job_info(j) for j in v.jobs(states, limit)])


@bp.get("/api/jobs/<job_id>")
def job(job_id):
    v = view()
    row = v.job(job_id)
    if row is None:
        return error(404, "no job %s" % job_id)
    return jsonify(v.job_info(row, with_report=True))


@bp.get("/api/jobs/<job_id>/files/<name>")
def job_file(job_id, name):
    from hostd.web.view import SHARE_HUNG, ShareFile
    opened = view().outbox_file(job_id, name)
    if opened is SHARE_HUNG:
        return error(503, "the folder holding job %s's files does not answer (a network share "
                          "away?); try again once it is back. Prints running on this node "
                          "are not affected" % job_id)
    if opened is None:
        return error(404, "no such file in the outbox of job %s" % job_id)
    f, st = opened
    inline = Path(name).suffix.lower() in (".png", ".svg", ".json")
    resp = send_file(f, as_attachment=not inline, download_name=name, max_age=10,
                     last_modified=st.st_mtime, etag="%d-%d" % (st.st_mtime_ns, st.st_size),
                     conditional=False)
    # Handed to the server a share read (1 MB) at a time, not in send_file's 8 kB: waitress
    # tries to send at each block, reading back what it buffered on disk, which for a
    # client that reads slowly is that much again per block (eight 42 MB downloads nobody
    # read: 14 s of CPU).
    resp.response = wrap_file(request.environ, f, buffer_size=ShareFile.READ_AHEAD)
    resp.content_length = st.st_size
    # send_file knows no size for a file object, so it would offer ranges it cannot serve.
    return resp.make_conditional(request.environ, accept_ranges=True,
                                 complete_length=st.st_size)


# -- actions ------------------------------------------------------------------------------

def _reply(result):
    status, body = result
    resp = jsonify(body)
    resp.status_code = status
    return resp


@bp.post("/api/jobs")
def upload():
    require_token()
    return _reply(save_upload(request.files.get("file"), request.files.get("sidecar"),
                              request.form.get("printer") or None))


@bp.post("/api/jobs/<job_id>/<action>")
def job_post(job_id, action):
    require_token()
    if action == "move":
        body = request.get_json(silent=True) or {}
        return _reply(move_in_queue(job_id, body.get("to", request.form.get("to"))))
    if action not in JOB_ACTIONS:
        return error(404, "unknown action %s; use %s or move" % (action, ", ".join(JOB_ACTIONS)))
    return _reply(job_action(job_id, action))


@bp.post("/api/printers/<name>/<action>")
def printer_post(name, action):
    require_token()
    if action not in PRINTER_ACTIONS:
        return error(404, "unknown action %s; use %s" % (action, ", ".join(PRINTER_ACTIONS)))
    return _reply(printer_action(name, action))


@bp.post("/api/queue")
def reorder():
    require_token()
    body = request.get_json(silent=True) or {}
    order = body.get("order")
    if not isinstance(order, list) or not all(isinstance(i, str) for i in order):
        return error(400, 'send {"order": [job ids, first to print first]}')
    queued = {j["id"] for j in view().queue()}
    unknown = [i for i in order if i not in queued]
    if unknown:
        return error(409, "not in the queue: " + ", ".join(unknown))
    return _reply(ask_daemon("reorder", json.dumps(order)))
