"""OctoPrint's Application Keys plugin on the page: clients ask, a person with the token decides.

``GET /plugin/appkeys/probe`` (204: keys can be had), ``POST /plugin/appkeys/request``
(201 and the app token to poll with), ``GET /plugin/appkeys/request/<app_token>`` (202
pending, 200 with the key once approved, 404 denied or expired); hostd's own
``GET /api/appkeys`` and ``POST /api/appkeys/<id>/approve|deny|revoke`` (web token), and
the status page's section with the same actions as forms.

:func:`client_problem` is the door of the OctoPrint client actions: an approved key in
``X-Api-Key``, or the web token. A wrong or revoked key is refused on every ``/api/`` path,
as OctoPrint does, with its error shape ``{"error": ...}``.
"""

import logging
import sqlite3

from flask import Blueprint, current_app, jsonify, request, url_for

from hostd.appkeys import FILE, KeyStore, clean_app
from hostd.errors import HostdError
from hostd.web import api, pages

bp = Blueprint("appkeys", __name__)
log = logging.getLogger("hostd.web")
MAX_PENDING = 20
KEY_ACTIONS = ("approve", "deny", "revoke")


def store():
    app = current_app
    if "HOSTD_KEYS" not in app.config:
        app.config["HOSTD_KEYS"] = KeyStore(api.view().config.state_dir)
    return app.config["HOSTD_KEYS"]


def octo_error(status, message, **extra):
    """OctoPrint's error answer: ``{"error": message}`` (with hostd's ``code`` beside it)."""
    resp = jsonify(dict(error=message, **extra))
    resp.status_code = status
    return resp


def _remote():
    return request.remote_addr or "unknown"


def client_problem():
    """None when the request may act as an OctoPrint client, else the 403 answer."""
    key = request.headers.get("X-Api-Key")
    if key:
        if not api.view().config.web.token:
            return octo_error(403, api.NO_TOKEN, code="appkeys.off")
        if store().check(key) is None:
            return octo_error(403, "Invalid API key", code="appkeys.invalid")
        return None
    problem = api.token_problem(api.bearer())
    if problem is None:
        return None
    return octo_error(403, "an application key (X-Api-Key) or the node's token (Authorization: "
                           "Bearer TOKEN) is required; request a key through /plugin/appkeys "
                           "and approve it on the status page", code="appkeys.required")


@bp.before_app_request
def refuse_bad_keys():
    if request.path.startswith("/api/") and request.headers.get("X-Api-Key"):
        try:
            valid = api.view().config.web.token and store().check(request.headers["X-Api-Key"])
        except (sqlite3.Error, OSError) as exc:     # a full or unreadable state folder
            return octo_error(503, "the application keys cannot be read (%s: %s); free space "
                                   "in the state folder" % (FILE, exc), code="appkeys.store")
        if not valid:
            return octo_error(403, "Invalid API key", code="appkeys.invalid")
    return None


@bp.app_context_processor
def keys_on_page():
    def appkeys():
        """The page's section: None when keys are off; never creates the store (a page must
        render on a full disk, and a node nobody asked a key of needs no file)."""
        config = api.view().config
        if not config.web.token:
            return None
        if not (config.state_dir / FILE).exists():
            return dict(pending=[], keys=[])
        try:
            return dict(pending=store().pending(), keys=store().keys())
        except (sqlite3.Error, OSError):
            return None
    return dict(appkeys=appkeys)


# -- the client's side ---------------------------------------------------------------------

@bp.get("/plugin/appkeys/probe")
def probe():
    if not api.view().config.web.token:
        return octo_error(404, "application keys are off on this node: " + api.NO_TOKEN,
                          code="appkeys.off")
    return "", 204


@bp.post("/plugin/appkeys/request")
def make_request():
    if not api.view().config.web.token:
        return octo_error(403, "application keys are off on this node: " + api.NO_TOKEN,
                          code="appkeys.off")
    body = request.get_json(silent=True)
    body = body if isinstance(body, dict) else request.form
    if len(store().pending()) >= MAX_PENDING:
        return octo_error(429, "%d key requests already wait for a decision on this node; "
                               "decide them on its status page first" % MAX_PENDING,
                          code="appkeys.too_many")
    try:
        app = clean_app(body.get("app"))
    except HostdError as exc:
        return octo_error(400, exc.text(), code=exc.code)
    app_token = store().request(app, body.get("user"), _remote())
    log.info("application key requested for %r from %s: approve it on the status page or "
             "with `hostd keys approve`", app, _remote())
    resp = jsonify(app_token=app_token)
    resp.status_code = 201
    resp.headers["Location"] = url_for("appkeys.poll", app_token=app_token, _external=True)
    return resp


@bp.get("/plugin/appkeys/request/<app_token>")
def poll(app_token):
    answer = store().poll(app_token)
    if answer is None:
        return octo_error(404, "no such key request: denied, expired or never made",
                          code="appkeys.no_request")
    if answer == "pending":
        resp = jsonify({})
        resp.status_code = 202
        return resp
    return jsonify(api_key=answer)


# -- the operator's side ---------------------------------------------------------------------

def key_action(ident, action):
    """(status, body) of approve/deny (a request id) or revoke (a key id or app name)."""
    try:
        result = getattr(store(), action)(ident)
    except HostdError as exc:
        return 404, dict(ok=False, error=exc.text(), code=exc.code)
    log.info("application keys: %s", result)
    return 200, dict(ok=True, result=result)


@bp.get("/api/appkeys")
def listing():
    api.require_token()
    return jsonify(pending=store().pending(), keys=store().keys())


@bp.post("/api/appkeys/<ident>/<action>")
def api_action(ident, action):
    api.require_token()
    if action not in KEY_ACTIONS:
        return api.error(404, "unknown action %s; use %s" % (action, ", ".join(KEY_ACTIONS)))
    status, body = key_action(ident, action)
    resp = jsonify(body)
    resp.status_code = status
    return resp


@bp.post("/actions/appkeys/<ident>/<action>")
def form_action(ident, action):
    if action not in KEY_ACTIONS:
        return api.error(404, "unknown action %s" % action)
    return pages.form_action(("approve", "revoke"), "key", ident, action,
                             lambda: key_action(ident, action))
