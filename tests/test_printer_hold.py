"""A print that ends without finishing holds its printer until a person resumes it:
the failed print is still on the bed, and the next job must not start on top of it."""

import dataclasses
import time

import pytest

from daemon_helpers import Pings, write_config, write_dome
from hostd import daemon as daemon_mod
from hostd import jobs as J
from hostd.config import load_config


def _daemon(tmp_path, fault):
    port = "sim://?time_scale=0&advanced_ok=1&boot_s=0&%s" % fault
    printers = [{"name": "p1", "profile": "generic-0.5mm", "baud": 2000000, "port": port}]
    config = load_config(write_config(tmp_path, printers=printers, heartbeat_s=0.2))
    config = dataclasses.replace(config, web=dataclasses.replace(config.web, port=None))
    d = daemon_mod.Daemon(config, notifier=Pings())
    d.setup()
    return d


def _run_until(d, predicate, timeout=60, what="condition"):
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "timed out waiting for " + what
        d.tick()
        time.sleep(0.02)


def _state(d, name):
    return {j["name"]: j["state"] for j in d.store.list()}.get(name)


@pytest.mark.parametrize("fault", ["fault_reset_line=200", "fault_disconnect_line=200&reconnect_s=0.2"])
def test_an_abnormal_end_holds_the_printer_until_resumed(tmp_path, fault):
    d = _daemon(tmp_path, fault)
    try:
        write_dome(d.config.drop_dir / "first.npy")
        _run_until(d, lambda: _state(d, "first.npy") == J.FAILED, what="the print to fail")
        slot = d.slots[0]
        assert slot.paused and "first.npy" in slot.held
        write_dome(d.config.drop_dir / "second.npy")
        _run_until(d, lambda: _state(d, "second.npy") == J.READY, what="the second plan")
        t = time.monotonic()
        while time.monotonic() - t < 3.0:            # the printer is back and idle, yet held
            d.tick()
            time.sleep(0.02)
        assert _state(d, "second.npy") == J.READY
        printer = d.store.printers()["p1"]
        assert printer["paused"] == 1 and "clear the bed" in printer["held"]
        from hostd.web.view import NodeView
        view = NodeView(d.config, d, db_path=d.config.db_path)
        card = [p for p in view.printers() if p["name"] == "p1"][0]
        assert "first.npy" in card["held"]
        assert d._do_resume("p1") == "resumed p1"
        assert slot.held is None and d.store.printers()["p1"]["held"] is None
        _run_until(d, lambda: _state(d, "second.npy") in (J.PRINTING, J.DONE, J.FAILED),
                   what="the second print to start after the resume")
    finally:
        d.shutdown()


def test_a_hold_outlives_a_restart(tmp_path):
    d = _daemon(tmp_path, "fault_reset_line=200")
    try:
        write_dome(d.config.drop_dir / "first.npy")
        _run_until(d, lambda: _state(d, "first.npy") == J.FAILED, what="the print to fail")
    finally:
        d.shutdown()
    d = _daemon(tmp_path, "fault_reset_line=200")
    try:
        assert d.slots[0].paused and "first.npy" in d.slots[0].held
    finally:
        d.shutdown()
