"""A full disk never stops a person from stopping a print: cancel and emergency stop act
on the printer first, then are recorded when the job store has room."""

import time

from daemon_helpers import fill_store, pty_simulator, ticking_daemon, write_dome
from hostd import jobs as J
from hostd.web.app import create_app

TOKEN = "full-disk-token"


def _jobs(d):
    """This thread's own view of the store (the daemon's connection is its loop's)."""
    store = J.JobStore(d.config.db_path, create=False)
    try:
        return store.list()
    finally:
        store.close()


def _printing(d):
    rows = _jobs(d)
    return rows and rows[0]["state"] == J.PRINTING


def _client(d):
    app = create_app(d.config, None, d)
    fill_store(app.config["HOSTD_VIEW"].store)   # the web's connection: its inserts fail
    return app.config["HOSTD_VIEW"], app.test_client()


def _wait(until, timeout=60, what="condition"):
    deadline = time.monotonic() + timeout
    while not until():
        assert time.monotonic() < deadline, "timed out waiting for " + what
        time.sleep(0.05)


def _config(config):
    import dataclasses
    return dataclasses.replace(config, web=dataclasses.replace(config.web, token=TOKEN))


def test_cancel_reaches_the_printer_when_the_store_is_full(tmp_path):
    with ticking_daemon(tmp_path, 0.01) as d:
        d.config = _config(d.config)
        write_dome(d.config.drop_dir / "dome.npy")
        _wait(lambda: _printing(d), what="the print")
        job_id = _jobs(d)[0]["id"]
        view, client = _client(d)
        r = client.post("/api/jobs/%s/cancel" % job_id,
                        headers={"Authorization": "Bearer " + TOKEN})
        assert r.status_code == 202 and "sent to the printer" in r.json["result"], r.json
        _wait(lambda: _jobs(d)[0]["state"] == J.CANCELLED, what="the cancel recorded")


def test_emergency_stop_reaches_the_printer_when_the_store_is_full(tmp_path):
    with pty_simulator(time_scale=0.01) as (sim, port), \
            ticking_daemon(tmp_path, 0.01, port=port) as d:
        d.config = _config(d.config)
        write_dome(d.config.drop_dir / "dome.npy")
        _wait(lambda: _printing(d), what="the print")
        view, client = _client(d)
        r = client.post("/api/printers/p1/estop", headers={"Authorization": "Bearer " + TOKEN})
        assert r.status_code == 202 and "sent to the printer" in r.json["result"], r.json
        assert d.slots[0].paused
        _wait(lambda: sim.firmware.halted, what="the firmware to halt")
