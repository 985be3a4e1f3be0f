"""LineFlow bookkeeping rules, driven directly (no port)."""

import random
from collections import Counter, deque

import pytest

from hostd.printer import protocol
from hostd.printer.errors import PrinterError
from hostd.printer.firmware import Firmware
from hostd.printer.flow import LineFlow
from hostd.printer.settings import LinkSettings
from hostd.printer.simconfig import SimConfig

from printer_helpers import moves

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


# -- scripted exchanges with the firmware model ------------------------------------------

def stream(lines, corrupt=(), slow_answer=None, slow_read=None):
    """Stream ``lines`` through LineFlow to the firmware model in steps of virtual time,
    dispatching its answers as the driver does; return (flow, firmware).

    A transmission is (line, how many times that line has been sent). ``corrupt``: these
    arrive with a bit flipped. ``slow_answer`` {transmission: steps}: the firmware's
    answers to it reach the host that much later (and so does all it says after them).
    ``slow_read`` {transmission: steps}: the firmware reads nothing more from its receive
    buffer for that long once it arrived. Where the driver would wait out ok_timeout_s
    for an answer that cannot come, a timeout is counted and recovered from as the driver
    does (expire, numbered M105 probe).
    """
    slow_answer, slow_read = slow_answer or {}, slow_read or {}
    flow = LineFlow(LinkSettings(rx_buffer_bytes=127), dict.fromkeys(STATS, 0), 10.0 / 250000)
    flow.reset(next_n=1, capacity=4)
    firmware = Firmware(SimConfig(advanced_ok=True, time_scale=0), random.Random(0))
    todo = deque((command, ("job", i + 1)) for i, command in enumerate(lines))
    times_sent = Counter()
    wire_back = deque()               # (step due at the host, reply)
    reads_from = 0                    # the firmware reads its buffer from this step on

    def answers(step, delay=0):
        due = max([step + 1 + delay] + [d for d, _ in wire_back])
        wire_back.extend((due, text) for text in firmware.out)
        firmware.out.clear()

    for step in range(1000):
        now = step * 0.01
        moved = bool(wire_back) and wire_back[0][0] <= step
        while wire_back and wire_back[0][0] <= step:
            reply = protocol.parse_reply(wire_back.popleft()[1].encode())
            if reply.kind == protocol.OK:
                flow.on_ok(reply.line, reply.line is None and reply.planner_free is not None)
            elif reply.kind == protocol.RESEND:
                flow.on_resend(reply.line, now)
            elif reply.kind == protocol.ERROR:
                flow.on_line_error(now)
        while not flow.window_full(now):
            if flow.replaying():
                sent, new = flow.replay_line(), False
            elif todo:
                sent, new = flow.new_line(*todo[0]), True
            else:
                break
            if not flow.fits(sent):
                break
            if new:
                todo.popleft()
            flow.commit(sent, new)
            moved = True
            times_sent[sent.n] += 1
            key = (sent.n, times_sent[sent.n])
            data = sent.data.replace(b" G1 ", b" G3 ", 1) if key in corrupt else sent.data
            firmware.feed(data, now)
            reads_from = max(reads_from, step + slow_read.get(key, 0))
            if step >= reads_from:
                firmware.step(now)
                answers(step, slow_answer.get(key, 0))
        if step >= reads_from:
            firmware.step(now)
            answers(step)
        if flow.settled() and not todo:
            return flow, firmware
        if not moved and not wire_back and step >= reads_from and now >= flow.resync_until:
            flow.stats["timeouts"] += 1      # nothing is coming: the driver's answer timeout
            flow.expire()
            todo.appendleft(("M105", ("probe",)))
    raise AssertionError("the exchange did not finish")


def job_lines(firmware):
    return [text for _, text in firmware.executed if text != "M105"]


def test_a_late_echo_of_a_resend_request_is_not_a_new_request():
    # Line 3 arrives corrupted; line 4, right behind it, is rejected with a second
    # "Resend: 3" that reaches the host only after it replayed 3 and 4. The replay was
    # read after that flush, so its oks follow: nothing is sent a third time and no ok
    # is waited for in vain.
    lines = moves(8)
    flow, firmware = stream(lines, corrupt={(3, 1)}, slow_answer={(4, 1): 10})
    stats = flow.stats
    assert (stats["timeouts"], stats["resends"], stats["lines_resent"]) == (0, 1, 2)
    assert firmware.stats["line_errors"] == 2
    assert job_lines(firmware) == lines


def test_a_late_echo_whose_flush_took_the_replay_sends_it_again():
    # The same, but the firmware is slow to read line 4: the replay is in its buffer when
    # it rejects 4, and the flush takes it. Only the replay going again keeps it moving.
    lines = moves(8)
    flow, firmware = stream(lines, corrupt={(3, 1)}, slow_read={(4, 1): 10})
    stats = flow.stats
    assert (stats["timeouts"], stats["resends"], stats["lines_resent"]) == (0, 1, 4)
    assert firmware.stats["line_errors"] == 2
    assert job_lines(firmware) == lines
