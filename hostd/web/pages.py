"""The status page's pages (node, job, farm) and its plain-HTML actions.

The actions work without JavaScript: forms post to ``/actions/...`` with the token in a
field, and destructive ones (cancel, emergency stop) need their confirmation box ticked.
"""

import time

from flask import abort, render_template, request

from hostd import jobs as J
from hostd.web import api


def add_pages(app, destructive):
    @app.get("/")
    def index():
        v = api.view()
        return render_template("index.html", s=v.status(history=True), J=J,
                               destructive=destructive)

    @app.get("/jobs/<job_id>")
    def job_page(job_id):
        v = api.view()
        row = v.job(job_id)
        if row is None:
            abort(404)
        return render_template("job.html", node_id=v.config.node_id,
                               job=v.job_info(row, _live(v, job_id), with_report=True), J=J)

    @app.get("/farm")
    def farm():
        v = api.view()
        return render_template("farm.html", node_id=v.config.node_id, nodes=v.nodes(),
                               dropped=v.drop_folder(), now=time.time())


def _live(view, job_id):
    """The printing job's live link snapshot, when it prints in this process."""
    if view.daemon is not None:
        for slot in view.daemon.slots:
            if slot.job_id == job_id and slot.link_job is not None:
                return slot.link_job.snapshot()
    return None


def form_action(destructive, kind, ident, action, run):
    """Check the form's token (and confirmation), run the action, answer with a page."""
    problem = api.token_problem(request.form.get("token"))
    if problem:
        return render_template("message.html", title="Refused", ok=False,
                               message=problem[1]), problem[0]
    if action in destructive and request.form.get("confirm") != "yes":
        return render_template("message.html", title="Not confirmed", ok=False,
                               message="%s is destructive: tick the confirmation box and "
                                       "send again." % action), 400
    status, body = run()
    message = body.get("result") or body.get("message") or body.get("error") or ""
    return render_template("message.html", title="%s %s %s" % (action, kind, ident),
                           ok=status < 300, message=message), status


def add_form_actions(app, destructive):
    @app.post("/actions/jobs/<job_id>/<action>")
    def form_job(job_id, action):
        if action in ("top", "up", "down", "bottom"):
            return form_action(destructive, "job", job_id, action,
                               lambda: api.move_in_queue(job_id, action))
        if action not in api.JOB_ACTIONS:
            abort(404)
        return form_action(destructive, "job", job_id, action,
                           lambda: api.job_action(job_id, action))

    @app.post("/actions/printers/<name>/<action>")
    def form_printer(name, action):
        if action not in api.PRINTER_ACTIONS:
            abort(404)
        return form_action(destructive, "printer", name, action,
                           lambda: api.printer_action(name, action))

    @app.post("/actions/upload")
    def form_upload():
        return form_action(destructive, "file", "", "upload", lambda: api.save_upload(
            request.files.get("file"), request.files.get("sidecar"),
            request.form.get("printer") or None))
