"""A print that ends without finishing holds its printer until a person resumes it:
the failed print is still on the bed, and the next job must not start on top of it."""

import time

import pytest

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J




def _state(d, name):
    return {j["name"]: j["state"] for j in d.store.list()}.get(name)


@pytest.mark.parametrize("fault", ["fault_reset_line=200", "fault_disconnect_line=200&reconnect_s=0.2"])
def test_an_abnormal_end_holds_the_printer_until_resumed(tmp_path, fault):
    d = in_process_daemon(tmp_path, 0, sim=fault)
    try:
        write_dome(d.config.drop_dir / "first.npy")
        tick_until(d, lambda: _state(d, "first.npy") == J.FAILED, what="the print to fail")
        slot = d.slots[0]
        assert slot.paused and "first.npy" in slot.held
        write_dome(d.config.drop_dir / "second.npy")
        tick_until(d, lambda: _state(d, "second.npy") == J.READY, what="the second plan")
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
        assert d.control.resume("p1") == "resumed p1"
        assert slot.held is None and d.store.printers()["p1"]["held"] is None
        tick_until(d, lambda: _state(d, "second.npy") in (J.PRINTING, J.DONE, J.FAILED),
                   what="the second print to start after the resume")
    finally:
        d.shutdown()


def test_a_hold_outlives_a_restart(tmp_path):
    d = in_process_daemon(tmp_path, 0, sim="fault_reset_line=200")
    try:
        write_dome(d.config.drop_dir / "first.npy")
        tick_until(d, lambda: _state(d, "first.npy") == J.FAILED, what="the print to fail")
    finally:
        d.shutdown()
    d = in_process_daemon(tmp_path, 0, sim="fault_reset_line=200")
    try:
        assert d.slots[0].paused and "first.npy" in d.slots[0].held
    finally:
        d.shutdown()
