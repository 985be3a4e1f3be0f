"""OctoPrint's file endpoints: uploads into the drop folder, and the node's inputs as files.

``POST /api/files/local`` (multipart ``file``; OctoPrint's ``select`` and ``print`` are
accepted; hostd's ``sidecar``, the YAML a dropped sidecar would hold, and ``printer``, a
printer or profile folder) checks the file as the intake checks a dropped one, before it
lands: a bad file is refused with the same coded reason (``code``) and never reaches the
drop folder. A good one is written under a hidden name in the drop folder (the watcher
passes over it) and renamed, sidecar first, so the intake takes it as any dropped file.
Every upload is queued to print in its turn once planned: nothing is selected or started
at once (``effectiveSelect``/``effectivePrint`` false).

``GET /api/files`` (and ``/api/files/local``) lists the node's jobs and the inputs still
in the drop folder in OctoPrint's file shape, with hostd's job beside each.
"""

import functools
import shutil
from pathlib import Path

from flask import Blueprint, current_app, jsonify, request, url_for

from hostd import jobs as J
from hostd.web import api, uploads
from hostd.web.appkeys import client_problem, octo_error
from hostd.watcher import INPUT_SUFFIXES, ignored

bp = Blueprint("octofiles", __name__)
MAX_SIDECAR_BYTES = 64 * 1024


def _entry(name, job=None, size=None, date=None):
    """One file in OctoPrint's shape; ``job`` (a store row) adds hostd's job beside it."""
    ext = Path(name).suffix.lower().lstrip(".")
    out = {"name": name, "display": name, "path": name, "origin": "local",
           "type": "model", "typePath": ["model", ext], "size": size, "date": date,
           "refs": {"resource": url_for("octofiles.one_file", name=name, _external=True)}}
    if job is not None:
        out["date"] = int(job["created_at"]) if job.get("created_at") else date
        out["prints"] = {"success": int(job["state"] == J.DONE),
                         "failure": int(job["state"] in (J.FAILED, J.CANCELLED,
                                                         J.INTERRUPTED))}
        out["hostd"] = {"job": job["id"], "state": job["state"], "error": job.get("error"),
                        "error_code": job.get("error_code"),
                        "resource": url_for("api.job", job_id=job["id"], _external=True)}
    return out


def _entries():
    v = api.view()
    out = [_entry(f["file"].rsplit("/", 1)[-1], size=f["bytes"]) for f in v.drop_folder()]
    out += [_entry(j["name"], job=j) for j in v.jobs(None, 200)]
    return out


@bp.get("/api/files")
@bp.get("/api/files/local")
def files():
    total, _, free = shutil.disk_usage(api.view().config.state_dir)
    return jsonify(files=_entries(), free=free, total=total)


@bp.get("/api/files/local/<name>")
def one_file(name):
    found = next((e for e in _entries() if e["name"] == name), None)
    if found is None:
        return octo_error(404, "no file %s on this node (its job may have been taken by "
                               "another node of the farm)" % name)
    return jsonify(found)


def _sidecar_text():
    """The ``sidecar`` field's YAML as bytes (a form field or a file part), or None."""
    part = request.files.get("sidecar")
    if part is not None and part.filename:
        data = part.stream.read(MAX_SIDECAR_BYTES + 1)
    else:
        text = request.form.get("sidecar")
        data = text.encode() if text else None
    if data is not None and len(data) > MAX_SIDECAR_BYTES:
        raise ValueError("the sidecar is larger than %d kB" % (MAX_SIDECAR_BYTES >> 10))
    return data


@bp.post("/api/files/local")
def upload():
    problem = client_problem()
    if problem:
        return problem
    if request.form.get("foldername"):
        return octo_error(400, "hostd keeps no folders of uploads: send a file")
    upload_ = request.files.get("file")
    name = api._clean_name(upload_.filename if upload_ else None)
    if not name:
        return octo_error(400, "send the file as multipart field `file` with a plain file name "
                               "(not hidden, no control characters)", code="upload.no_file")
    if Path(name).suffix.lower() not in INPUT_SUFFIXES or ignored(name):
        return octo_error(415, "%s: not an input type hostd plans (%s), or a name the drop "
                               "folder ignores" % (name, " ".join(INPUT_SUFFIXES)),
                          code="heightfield.unsupported_type")
    try:
        sidecar = _sidecar_text()
    except ValueError as exc:
        return octo_error(400, str(exc), code="sidecar.too_large")
    v = api.view()
    folder = Path(v.config.drop_dir)
    target = request.form.get("printer") or request.args.get("printer")
    if target:
        known = {p.name for p in v.config.printers} | {p.profile for p in v.config.printers}
        if target not in known:
            return octo_error(400, "no printer or profile %s on this node" % target)
        folder = folder / target
    from hostd.web.view import SHARE_HUNG
    check = functools.partial(_check, name=name, side_name=Path(name).stem + ".yaml")
    saved = v.share_write(uploads.store, folder, name, upload_, sidecar, check,
                          timeout_s=current_app.config.get("HOSTD_SHARE_WRITE_S"))
    if saved is SHARE_HUNG:
        return octo_error(503, "the drop folder (%s) does not answer (a network share away?): "
                               "the upload was not taken; try again once it answers"
                          % v.config.drop_dir)
    if isinstance(saved, OSError):
        return octo_error(500, "cannot save the upload: %s" % saved.strerror)
    if not isinstance(saved, Path):          # the intake's own refusal, with its code
        return octo_error(415 if saved.code == "heightfield.unsupported_type" else 400,
                          saved.text(), code=saved.code)
    return _uploaded(saved.relative_to(v.config.drop_dir).as_posix(), saved.name)


def _uploaded(rel, name):
    resource = url_for("octofiles.one_file", name=name, _external=True)
    resp = jsonify(done=True, effectiveSelect=False, effectivePrint=False,
                   files={"local": {"name": name, "path": rel, "display": name,
                                    "origin": "local", "refs": {"resource": resource}}})
    resp.status_code = 201
    resp.headers["Location"] = resource
    return resp


def _check(tmp, side_tmp, *, name, side_name):
    """The intake's checks of a dropped file and its sidecar: None, or the PipelineError
    naming the upload (not the hidden name it was checked under)."""
    from pipeline.errors import PipelineError
    from pipeline.input.heightfield import check_file
    from pipeline.input.sidecar import load_sidecar
    try:
        check_file(tmp)
    except PipelineError as exc:
        exc.file = name
        return exc
    try:
        if side_tmp is not None:
            load_sidecar(side_tmp)
    except PipelineError as exc:
        exc.file = side_name
        return exc
    return None
