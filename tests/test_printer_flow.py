"""LineFlow bookkeeping rules, driven directly (no port)."""

import pytest

from hostd.printer.errors import PrinterError
from hostd.printer.flow import LineFlow
from hostd.printer.settings import LinkSettings

STATS = ("lines_sent", "bytes_sent", "resends", "lines_resent", "timeouts", "max_in_flight_lines",
         "max_in_flight_bytes", "oks")


def make_flow(capacity=4):
    flow = LineFlow(LinkSettings(rx_buffer_bytes=127), dict.fromkeys(STATS, 0), 10.0 / 115200)
    flow.reset(next_n=3, capacity=capacity)
    return flow


def send(flow, count):
    sent = []
    for i in range(count):
        line = flow.new_line("G1 X%d" % i, ("job", i + 1))
        flow.commit(line, True)
        sent.append(line)
    return sent


def test_ok_with_line_number_resolves_lost_oks():
    flow = make_flow()
    send(flow, 3)                                 # lines 3, 4, 5
    assert [s.n for s in flow.on_ok(5)] == [3, 4, 5]
    assert flow.settled()


def test_resend_replays_once_and_absorbs_the_echoes():
    flow = make_flow()
    send(flow, 4)                                 # 3..6 in flight, 3 was corrupted
    accepted, honoured = flow.on_resend(3, now=10.0)
    assert honoured and accepted == [] and flow.cursor == 3
    assert flow.on_ok(None) is None               # the ok after Resend confirms nothing
    # 4 and 5 were still on the wire: each is rejected with another "Resend: 3".
    for _ in range(2):
        flow.on_line_error(10.001)
        assert flow.on_resend(3, now=10.001) == ([], False)
        assert flow.on_ok(None) is None
    assert flow.window_full(10.002)               # still waiting for stragglers
    assert not flow.window_full(11.0)
    assert flow.replay_line().n == 3
    assert flow.stats["resends"] == 1


def test_timeout_then_probe_confirms_the_lines_in_limbo():
    flow = make_flow(capacity=1)
    send(flow, 1)                                 # line 3: its ok was lost
    flow.expire()
    probe = flow.new_line("M105", ("probe",))
    flow.commit(probe, True)
    assert sorted(s.n for s in flow.on_ok(None)) == [3, 4]
    assert flow.settled()


def test_resend_after_timeout_keeps_accepted_lines_only():
    flow = make_flow(capacity=1)
    send(flow, 1)                                 # line 3 never arrived
    flow.expire()
    flow.commit(flow.new_line("M105", ("probe",)), True)
    accepted, honoured = flow.on_resend(3, now=1.0)
    assert honoured and accepted == [] and flow.cursor == 3


def test_resend_of_an_acknowledged_line_is_replayed_and_counted():
    flow = make_flow()
    send(flow, 2)
    flow.on_ok(3)       # in truth the ok of something else: line 3 never arrived
    accepted, honoured = flow.on_resend(3, now=1.0)
    assert honoured and flow.cursor == 3
    assert flow.stats["misattributed_oks"] == 1


def test_resend_of_a_line_no_longer_in_history_is_an_error():
    flow = make_flow()
    with pytest.raises(PrinterError) as err:
        flow.on_resend(1, now=1.0)
    assert err.value.code == "resend"


def test_window_counts_lines_and_bytes():
    flow = make_flow(capacity=4)
    sent = send(flow, 2)
    big = flow.new_line("G1 X1" + " Y1" * 35, ("job", 3))
    assert flow.fifo_bytes + len(big.data) > 127 and not flow.fits(big)
    send(flow, 2)
    assert flow.window_full(0.0)                  # 4 lines in flight = capacity
    flow.on_ok(sent[0].n)
    assert not flow.window_full(0.0)
