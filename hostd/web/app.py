"""The Flask app: the status page, the farm view, the JSON API, the OctoPrint subset, /metrics.

``create_app(config, store=None, daemon=None)``: ``store`` (a JobStore or None) only
names the database; each web thread opens its own connection. With ``daemon`` (the
running :class:`hostd.daemon.Daemon` in this process) printers show live temperatures
and line counters; without it, what the daemon last wrote to the store.

The page is plain HTML (works without JavaScript: forms post to ``/actions/...`` with
the token in a field); ``static/hostd.js`` polls ``/api/status`` to update it live and
sends actions to the API with the token kept in the tab's sessionStorage.
"""

import time

from flask import Flask, render_template, request

from hostd import jobs as J
from hostd.errors import HostdError
from hostd.web import api, hosts, pages
from hostd.web.view import NodeView

MAX_UPLOAD_BYTES = 64 * 1024 * 1024
DESTRUCTIVE = ("cancel", "estop", "approve")
CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
       "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'")


def _duration(seconds):
    if seconds is None:
        return "–"
    seconds = int(seconds)
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return "%d:%02d:%02d" % (h, m, s) if h else "%d:%02d" % (m, s)


def _when(ts):
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(ts)) if ts else "–"


def _chart_points(samples, width=300, height=60, lo=0.0, hi=260.0):
    """SVG polyline points of (t, current, target) samples, scaled to the box."""
    if not samples:
        return ""
    t0, t1 = samples[0][0], samples[-1][0]
    span = (t1 - t0) or 1.0
    pts = []
    for t, cur, _ in samples:
        if cur is None:
            continue
        x = (t - t0) / span * width
        y = height - (min(max(cur, lo), hi) - lo) / (hi - lo) * height
        pts.append("%.1f,%.1f" % (x, y))
    return " ".join(pts)


def create_app(config, store=None, daemon=None):
    app = Flask(__name__)
    app.config.update(MAX_CONTENT_LENGTH=MAX_UPLOAD_BYTES, HOSTD_ACTION_WAIT_S=5.0,
                      JSON_SORT_KEYS=False)
    app.json.sort_keys = False
    app.config["HOSTD_VIEW"] = NodeView(config, daemon, db_path=getattr(store, "path", None))
    from hostd.web import metrics, octoprint
    app.register_blueprint(api.bp)
    app.register_blueprint(octoprint.bp)
    app.register_blueprint(metrics.bp)
    from hostd.web import appkeys, octoclient, octofiles
    for module in (appkeys, octoclient, octofiles):
        app.register_blueprint(module.bp)
    app.jinja_env.filters.update(duration=_duration, when=_when, chart=_chart_points,
                                  sentence=problem_sentence)
    app.context_processor(lambda: {"node_id": config.node_id,
                                   "actions_enabled": bool(config.web.token)})
    app.after_request(security_headers)
    add_error_pages(app)
    pages.add_pages(app, DESTRUCTIVE)
    pages.add_form_actions(app, DESTRUCTIVE)
    app.wsgi_app = hosts.HostGuard(app.wsgi_app, hosts.Names(config.web))
    return app


def problem_sentence(problem):
    """A report's warning (code, message, fix) as an operator reads it: what, then the fix,
    without the Markdown backticks the CLI's text carries."""
    if not isinstance(problem, dict):
        return str(problem)
    text = str(problem.get("message", "")).strip().rstrip(".")
    text = text[:1].upper() + text[1:] + "."
    if problem.get("fix"):
        fix = str(problem["fix"]).strip().rstrip(".")
        text += " Fix: " + fix[:1].upper() + fix[1:] + "."
    return text.replace("`", "")


def security_headers(resp):
    """What a browser may do with our answers: our own scripts and styles only; files
    from the outbox are sandboxed (an SVG or HTML there runs nothing)."""
    resp.headers.setdefault("Content-Security-Policy", CSP)
    resp.headers["X-Content-Type-Options"] = "nosniff"
    resp.headers["Referrer-Policy"] = "no-referrer"
    if request.path.startswith("/api/jobs/") and "/files/" in request.path:
        resp.headers["Content-Security-Policy"] = "sandbox; default-src 'none'; " \
                                                  "img-src 'self'; style-src 'unsafe-inline'"
    return resp


def add_error_pages(app):
    """Errors as JSON under /api/, as a page elsewhere."""

    @app.errorhandler(413)
    def too_large(_exc):
        return api.error(413, "the upload is larger than %d MB" % (MAX_UPLOAD_BYTES >> 20))

    @app.errorhandler(HostdError)
    def refused(exc):
        # e.g. jobs.disk_full: an action cannot be recorded while the job database is full.
        status = 503 if exc.code == J.DISK_FULL else 409
        if request.path.startswith("/api/"):
            return api.error(status, exc.text(), code=exc.code)
        return render_template("message.html", title="Not done", ok=False,
                               message=exc.text()), status

    @app.errorhandler(404)
    def not_found(_exc):
        if request.path.startswith("/api/"):
            return api.error(404, "not found")
        return render_template("message.html", title="Not found", ok=False,
                               message="There is nothing at this address."), 404
