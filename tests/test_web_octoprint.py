"""OctoPrint-compatible endpoints and /metrics: documented fields, types and meanings."""

import time
from types import SimpleNamespace

import pytest

from hostd.printer.temps import TemperatureLog
from hostd.web.app import create_app
from test_web_api import Node


class FakeLinkJob:
    def __init__(self, confirmed, total):
        self.confirmed, self.total = confirmed, total

    def snapshot(self):
        return dict(total=self.total, confirmed=self.confirmed, last_confirmed_line=4,
                    seconds=40.0)


def fake_daemon(node, state="printing", with_job=True):
    temps = TemperatureLog()
    now = time.time()
    temps.update({"T": (180.0, 200.0), "B": (55.0, 60.0)}, now - 10)
    temps.update({"T": (199.5, 200.0), "B": (59.8, 60.0)}, now)
    sim = SimpleNamespace(firmware=SimpleNamespace(stats={"starvation_s": 1.25}))
    printer = SimpleNamespace(temperatures=temps, simulator=sim,
                              stats={"lines_sent": 1234, "resends": 3, "lines_resent": 3,
                                     "timeouts": 0})
    slot = SimpleNamespace(name="sim", printer=printer, state=state, paused=False, held=None,
                           job_id=node.printing if with_job else None,
                           link_job=FakeLinkJob(1, 4) if with_job else None, error=None, last_error=None,
                           config=node.config.printers[0])
    return SimpleNamespace(slots=[slot], problem="share: gone", dropped=lambda: [
        {"file": "a.npy", "bytes": 10, "complete": False, "this_node": True}],
        problems=lambda: {"share": "share: gone"})


@pytest.fixture
def live(tmp_path):
    node = Node(tmp_path)
    node.app = create_app(node.config, store=node.store, daemon=fake_daemon(node))
    node.client = node.app.test_client()
    yield node
    node.store.close()


def test_version(live):
    v = live.client.get("/api/version").json
    assert set(v) == {"api", "server", "text"}
    assert all(isinstance(v[k], str) for k in v) and v["text"].startswith("OctoPrint ")


def test_printer_fields_and_types(live):
    r = live.client.get("/api/printer")
    assert r.status_code == 200
    p = r.json
    assert set(p) == {"temperature", "sd", "state"}
    assert p["temperature"]["tool0"] == {"actual": 199.5, "target": 200.0, "offset": 0}
    assert p["temperature"]["bed"] == {"actual": 59.8, "target": 60.0, "offset": 0}
    assert p["state"]["text"] == "Printing"
    flags = p["state"]["flags"]
    assert set(flags) == {"operational", "paused", "printing", "pausing", "cancelling",
                          "sdReady", "error", "ready", "closedOrError"}
    assert all(isinstance(v, bool) for v in flags.values())
    assert flags["printing"] and flags["operational"] and not flags["paused"]
    assert not flags["closedOrError"] and not flags["ready"]
    assert p["sd"] == {"ready": False}
    only = live.client.get("/api/printer?exclude=temperature,sd").json
    assert set(only) == {"state"}
    assert live.client.get("/api/printer?printer=nope").status_code == 404


def test_printer_offline_is_409(tmp_path):
    node = Node(tmp_path)
    node.app = create_app(node.config, daemon=fake_daemon(node, "disconnected", False))
    r = node.app.test_client().get("/api/printer")
    assert r.status_code == 409 and "not operational" in r.json["error"]
    r = node.app.test_client().get("/api/job")
    assert r.json["state"] == "Offline" and r.json["progress"]["completion"] is None
    node.store.close()


def test_job_fields_and_types(live):
    j = live.client.get("/api/job").json
    assert set(j) == {"job", "progress", "state"}
    assert j["state"] == "Printing"
    f = j["job"]["file"]
    assert f["name"] == "dome.gcode" and f["origin"] == "local" and f["display"] == "dome.npy"
    assert isinstance(f["size"], int) and isinstance(f["date"], int)
    assert j["job"]["estimatedPrintTime"] == 100.0
    assert j["job"]["filament"]["tool0"]["length"] == 12.5
    pr = j["progress"]
    assert pr["completion"] == 25.0                    # percent, from the live link: 1 of 4
    assert isinstance(pr["filepos"], int) and 0 < pr["filepos"] < f["size"]
    assert pr["printTime"] == 40 and pr["printTimeLeft"] == 120
    assert pr["printTimeLeftOrigin"] == "linear"


def test_job_idle(tmp_path):
    node = Node(tmp_path)
    app = create_app(node.config, daemon=fake_daemon(node, "idle", False))
    j = app.test_client().get("/api/job").json
    assert j["state"] == "Operational"
    assert j["job"]["file"]["name"] is None and j["progress"]["completion"] is None
    p = app.test_client().get("/api/printer").json
    assert p["state"]["flags"]["ready"] is True and p["state"]["flags"]["printing"] is False
    node.store.close()


def _samples(text):
    from prometheus_client.parser import text_string_to_metric_families
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def test_metrics(live):
    live.store.set_state(live.queued, "planning")
    live.store.set_state(live.queued, "ready", "planned in 12.5 s")
    r = live.client.get("/metrics")
    assert r.status_code == 200 and r.content_type.startswith("text/plain")
    m = _samples(r.get_data(as_text=True))
    assert m[("hostd_jobs", (("state", "queued"),))] == 1
    assert m[("hostd_jobs", (("state", "ready"),))] == 1
    assert m[("hostd_prints_total", (("result", "failed"),))] == 1
    assert m[("hostd_prints_total", (("result", "done"),))] == 0
    assert m[("hostd_temperature_celsius", (("heater", "T"), ("printer", "sim")))] == 199.5
    assert m[("hostd_temperature_target_celsius", (("heater", "B"), ("printer", "sim")))] == 60
    assert m[("hostd_printer_state", (("printer", "sim"), ("state", "printing")))] == 1
    assert m[("hostd_serial_lines_sent_total", (("printer", "sim"),))] == 1234
    assert m[("hostd_serial_resends_total", (("printer", "sim"),))] == 3
    assert m[("hostd_planner_starvation_seconds_total", (("printer", "sim"),))] == 1.25
    assert m[("hostd_plan_duration_seconds_count", ())] == 1
    assert m[("hostd_plan_duration_seconds_sum", ())] == 12.5
    assert m[("hostd_plan_duration_seconds_bucket", (("le", "10.0"),))] == 0
    assert m[("hostd_plan_duration_seconds_bucket", (("le", "30.0"),))] == 1
    assert m[("hostd_problem", (("kind", "share"),))] == 1
    assert m[("hostd_problem", (("kind", "stuck"),))] == 0
    assert m[("hostd_drop_folder_files", (("state", "copying"),))] == 0   # gone meanwhile
    (live.config.drop_dir / "a.npy").write_bytes(b"1234567890")
    m = _samples(live.client.get("/metrics").get_data(as_text=True))
    assert m[("hostd_drop_folder_files", (("state", "copying"),))] == 1
    assert m[("hostd_drop_folder_files", (("state", "waiting"),))] == 0


def test_prints_total_never_goes_down_after_a_requeue(live):
    def cancelled():
        m = _samples(live.client.get("/metrics").get_data(as_text=True))
        return m[("hostd_prints_total", (("result", "cancelled"),))]
    live.store.set_state(live.printing, "cancelled", "cancelled by a person")
    assert cancelled() == 1
    live.store.set_state(live.printing, "queued", "requeued by a person")
    assert cancelled() == 1


def test_prints_total_counts_cancelled_prints_not_cancelled_queued_jobs(live):
    """A job cancelled in the queue never printed: it is no cancelled print."""
    def cancelled():
        m = _samples(live.client.get("/metrics").get_data(as_text=True))
        return m[("hostd_prints_total", (("result", "cancelled"),))]
    live.store.set_state(live.queued, "cancelled", "cancelled by a person")
    assert cancelled() == 0
    live.store.set_state(live.printing, "cancelled", "the print was cancelled by a person")
    assert cancelled() == 1
    # printed once, requeued, cancelled again before it printed: still one print
    live.store.set_state(live.printing, "queued", "requeued by a person")
    live.store.set_state(live.printing, "cancelled", "cancelled by a person")
    assert cancelled() == 1


def test_metrics_count_printers_waiting_for_a_person(tmp_path):
    node = Node(tmp_path)
    daemon = fake_daemon(node, "idle", False)
    app = create_app(node.config, daemon=daemon)

    def waiting():
        m = _samples(app.test_client().get("/metrics").get_data(as_text=True))
        return m[("hostd_printers_waiting_for_person", ())]
    assert waiting() == 0
    daemon.slots[0].held = "the print of dome.npy finished: take it off the bed"
    assert waiting() == 1
    status = app.test_client().get("/api/status").json
    assert status["waiting_for_person"] == ["sim"]
    assert status["printers"][0]["waiting_for_person"] is True
    assert "dome.npy finished" in status["printers"][0]["held"]
    node.store.close()


def test_page_shows_live_values(live):
    html = live.client.get("/").get_data(as_text=True)
    assert 'data-printer="sim"' in html and "200" in html and "25.0" in html
    assert "<polyline" in html and "layer" in html
    assert "https://" not in html and "http://" not in html     # nothing from the internet
