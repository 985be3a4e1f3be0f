"""A printer that stopped answering mid-print and came back: the job fails and the printer
is held with the reason on its card; resuming it reconnects the link (it stayed in error
until a restart before)."""

import dataclasses
import time

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from hostd import slot as slot_mod
from hostd.web.view import NodeView

STALL_S = 3.0


def _quick_give_up(monkeypatch):
    real = slot_mod.link_settings

    def quick(printer_config):   # give up on a silent printer in about a second
        return dataclasses.replace(real(printer_config), ok_timeout_s=0.5, max_timeouts=1)
    monkeypatch.setattr(slot_mod, "link_settings", quick)


def test_a_printer_that_stalled_and_came_back_reconnects_when_resumed(tmp_path, monkeypatch):
    _quick_give_up(monkeypatch)
    d = in_process_daemon(tmp_path, 0, sim="fault_stall_line=150&stall_s=%g" % STALL_S)
    try:
        write_dome(d.config.drop_dir / "dome.npy")
        slot = d.slots[0]
        job = lambda: d.store.list()[0]                      # noqa: E731
        tick_until(d, lambda: d.store.list() and job()["state"] == J.FAILED, what="the failure")
        assert "not responding" in job()["error"]
        assert slot.state == "error" and slot.paused
        t = time.monotonic()
        while time.monotonic() - t < STALL_S:                # the board is back meanwhile
            d.tick()
            time.sleep(0.05)
        card = [p for p in NodeView(d.config, d, db_path=d.config.db_path).printers()
                if p["name"] == "p1"][0]
        assert card["state"] == "error" and "not responding" in card["error"]
        assert card["temperatures_stale"]
        assert d.control.resume("p1").endswith("reconnecting")
        tick_until(d, lambda: slot.state == "idle", what="the printer to reconnect")
        assert slot.last_error is None
    finally:
        d.shutdown()


def test_after_a_thermal_runaway_the_card_says_why(tmp_path):
    d = in_process_daemon(tmp_path, 0, sim="fault_runaway_line=150")
    try:
        write_dome(d.config.drop_dir / "dome.npy")
        tick_until(d, lambda: d.store.list() and d.store.list()[0]["state"] == J.FAILED,
               what="the failure")
        card = NodeView(d.config, d, db_path=d.config.db_path).printers()[0]
        assert card["state"] == "error" and "Thermal Runaway" in card["error"]
        assert card["temperatures_stale"]
    finally:
        d.shutdown()
