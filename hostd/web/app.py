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

from flask import Flask, abort, render_template, request

from hostd import jobs as J
from hostd.errors import HostdError
from hostd.web import api
from hostd.web.view import NodeView

MAX_UPLOAD_BYTES = 64 * 1024 * 1024
DESTRUCTIVE = ("cancel", "estop")
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
    app.jinja_env.filters.update(duration=_duration, when=_when, chart=_chart_points)

    @app.after_request
    def headers(resp):
        resp.headers.setdefault("Content-Security-Policy", CSP)
        resp.headers["X-Content-Type-Options"] = "nosniff"
        resp.headers["Referrer-Policy"] = "no-referrer"
        if request.path.startswith("/api/jobs/") and "/files/" in request.path:
            resp.headers["Content-Security-Policy"] = "sandbox; default-src 'none'; " \
                                                      "img-src 'self'; style-src 'unsafe-inline'"
        return resp

    @app.context_processor
    def node():
        return {"node_id": config.node_id}

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

    # -- pages ------------------------------------------------------------------------------

    @app.get("/")
    def index():
        v = api.view()
        return render_template("index.html", s=v.status(history=True), J=J,
                               destructive=DESTRUCTIVE)

    @app.get("/jobs/<job_id>")
    def job_page(job_id):
        v = api.view()
        row = v.job(job_id)
        if row is None:
            abort(404)
        live = None
        if v.daemon is not None:
            for slot in v.daemon.slots:
                if slot.job_id == job_id and slot.link_job is not None:
                    live = slot.link_job.snapshot()
        return render_template("job.html", node_id=v.config.node_id,
                               job=v.job_info(row, live, with_report=True), J=J)

    @app.get("/farm")
    def farm():
        v = api.view()
        return render_template("farm.html", node_id=v.config.node_id, nodes=v.nodes(),
                               dropped=v.drop_folder(), now=time.time())

    # -- plain-HTML actions (no JavaScript) --------------------------------------------------

    def _form_action(kind, ident, action, run):
        problem = api.token_problem(request.form.get("token"))
        if problem:
            return render_template("message.html", title="Refused", ok=False,
                                   message=problem[1]), problem[0]
        if action in DESTRUCTIVE and request.form.get("confirm") != "yes":
            return render_template("message.html", title="Not confirmed", ok=False,
                                   message="%s is destructive: tick the confirmation box and "
                                           "send again." % action), 400
        status, body = run()
        message = body.get("result") or body.get("message") or body.get("error") or ""
        return render_template("message.html", title="%s %s %s" % (action, kind, ident),
                               ok=status < 300, message=message), status

    @app.post("/actions/jobs/<job_id>/<action>")
    def form_job(job_id, action):
        if action in ("top", "up", "down", "bottom"):
            return _form_action("job", job_id, action,
                                lambda: api.move_in_queue(job_id, action))
        if action not in api.JOB_ACTIONS:
            abort(404)
        return _form_action("job", job_id, action, lambda: api.job_action(job_id, action))

    @app.post("/actions/printers/<name>/<action>")
    def form_printer(name, action):
        if action not in ("estop", "pause", "resume"):
            abort(404)
        return _form_action("printer", name, action, lambda: api.printer_action(name, action))

    @app.post("/actions/upload")
    def form_upload():
        return _form_action("file", "", "upload", lambda: api.save_upload(
            request.files.get("file"), request.files.get("sidecar"),
            request.form.get("printer") or None))

    return app
