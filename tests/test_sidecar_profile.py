"""A sidecar names a profile this node has, never a file: no file's content leaks
through a profile error, and a requeue reads the sidecar again."""

import time

import pytest

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from pipeline.errors import InvalidProfile, InvalidSidecar
from pipeline.input.sidecar import load_sidecar
from pipeline.profiles.profile import load_profile

SECRET = "MIIEvQIBADANBgkqhkiG9w0BAQEFAASCBKcwggSjAgEAAoIBAQC7VJTUt9Us8cKj"
PEM = "-----BEGIN PRIVATE KEY-----\n%s\n-----END PRIVATE KEY-----\n" % SECRET
PASSWD = "root:x:0:0:root:/root:/bin/bash\nsecretuser:x:1000:1000::/home/secretuser:/bin/sh\n"


@pytest.mark.parametrize("value", ["/etc/passwd", "../../keys/key.pem", "generic-0.5mm.yaml",
                                   "a b", "C:\\\\keys\\\\k"])
def test_a_sidecar_profile_must_be_a_name(tmp_path, value):
    side = tmp_path / "x.yaml"
    side.write_text('profile: "%s"\n' % value)
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(side)
    assert err.value.code == "sidecar.profile"
    assert "generic-0.5mm" in err.value.fix


def test_a_name_is_taken(tmp_path):
    side = tmp_path / "x.yaml"
    side.write_text("profile: prusa-mk3s-0.4mm\n")
    assert load_sidecar(side).profile == "prusa-mk3s-0.4mm"


@pytest.mark.parametrize("text", [PEM, PASSWD, "token: %s\n" % SECRET,
                                  "name: x\nspeeds_mm_s: {print: %s}\n" % SECRET])
def test_a_profile_error_never_quotes_the_file(tmp_path, text):
    path = tmp_path / "notaprofile.yaml"
    path.write_text(text)
    with pytest.raises(InvalidProfile) as err:
        load_profile(path)
    shown = err.value.text() + repr(err.value.to_dict())
    for secret in (SECRET, "secretuser", "/bin/bash"):
        assert secret not in shown


def _requeue(d, job_id):
    cli = J.JobStore(d.config.db_path)
    req = cli.request("requeue", job_id)
    deadline = time.monotonic() + 20
    while True:
        answer = cli.wait_answer(req, timeout_s=0.01)
        if answer is not None:
            return answer
        assert time.monotonic() < deadline
        d.tick()


def test_requeue_of_a_sidecar_naming_a_key_file_discloses_nothing(tmp_path):
    d = in_process_daemon(tmp_path, time_scale=0)
    try:
        key = tmp_path / "key.pem"
        key.write_text(PEM)
        inp = write_dome(d.config.drop_dir / "x.npy")
        inp.with_name("x.yaml").write_text("pixel_mm: 1.0\nprofile: %s\n" % key)
        tick_until(d, lambda: [j for j in d.store.list() if j["state"] == J.FAILED])
        [job] = d.store.list()
        assert job["error_code"] == "sidecar.profile"
        _requeue(d, job["id"])
        tick_until(d, lambda: d.store.get(job["id"])["state"] == J.FAILED)
        job = d.store.get(job["id"])
        told = (d.config.failed_dir / "x.error.txt").read_text()
        events = " ".join(e["message"] for e in d.store.events(job["id"]))
        for text in (job["error"] or "", told, events):
            assert SECRET not in text and "BEGIN PRIVATE KEY" not in text
    finally:
        d.shutdown()


def test_requeue_reads_the_sidecar_again(tmp_path):
    """A job failed for a profile no printer here uses; the person fixes the sidecar in
    failed/ and requeues: the job takes the fixed profile and is planned."""
    d = in_process_daemon(tmp_path, time_scale=0)
    try:
        inp = write_dome(d.config.drop_dir / "y.npy")
        inp.with_name("y.yaml").write_text("pixel_mm: 1.0\nprofile: prusa-mk3s-0.4mm\n")
        tick_until(d, lambda: [j for j in d.store.list() if j["state"] == J.FAILED])
        [job] = d.store.list()
        assert job["error_code"] == "job.no_printer"
        (d.config.failed_dir / "y.yaml").write_text("pixel_mm: 1.0\nprofile: generic-0.5mm\n"
                                                     "copies: 2\n")
        _requeue(d, job["id"])
        job = d.store.get(job["id"])
        assert job["profile"] == "generic-0.5mm" and job["copies"] == 2
        tick_until(d, lambda: d.store.get(job["id"])["state"] not in (J.QUEUED, J.PLANNING),
                   timeout=120)
        assert d.store.get(job["id"])["state"] != J.FAILED, d.store.get(job["id"])["error"]
    finally:
        d.shutdown()
