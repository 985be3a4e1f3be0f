"""The serial link must keep up with the file: chords merged within a distance tolerance,
the link's capacity in the report, and a job slowed (M220) where it still cannot keep up."""

import dataclasses
import io
import time

import numpy as np
import pytest

from daemon_helpers import in_process_daemon, pty_simulator, write_dome
from gcode_parser import parse, point_polyline_distance
from hostd import jobs as J
from hostd.feed import job_feed
from hostd.planner import link_problems
from hostd.printer.protocol import frame
from pipeline.gcode.chords import merge_chords
from pipeline.gcode.link import LINK_SHARE, feed_percent, framing_bytes, link_moves_per_s
from pipeline.gcode.writer import write_gcode
from pipeline.profiles.profile import load_profile

PROFILE = load_profile("generic-0.5mm")


def spiral(turns=6, seg_mm=0.2):
    """A finely sampled spiral (one trace) whose shrink steps every 40 mm of path."""
    t = np.linspace(0, turns * 2 * np.pi, int(turns * 2 * np.pi * 12 / seg_mm))
    r = 4 + 0.5 * t / (2 * np.pi)
    p = 100.0 + np.c_[r * np.cos(t), r * np.sin(t)]
    s = np.cumsum(np.hypot(*np.diff(p, axis=0).T))
    return p, 0.1 + 0.05 * (s // 40)


def _with(profile, **toolpath):
    return dataclasses.replace(profile, toolpath=dataclasses.replace(profile.toolpath, **toolpath))


def test_merged_chords_stay_within_the_tolerance_and_never_mix_shrinks():
    p, sig = spiral()
    (q,), (v,) = merge_chords([p], [sig[:, None]], 0.02, 0.005)
    assert len(q) < len(p) / 3
    assert point_polyline_distance(p, q).max() <= 0.02 + 1e-9
    # Every original point is kept or lies inside one merged segment of its own shrink.
    kept = np.flatnonzero((np.abs(p[:, None] - q[None]).sum(axis=2) < 1e-12).any(axis=1))
    for a, b, value in zip(kept[:-1], kept[1:], v[:, 0]):
        assert np.ptp(sig[a:b]) < 0.005 and abs(value - sig[a:b].mean()) < 1e-12


def test_no_tolerance_keeps_every_chord():
    p, sig = spiral(turns=1)
    (q,), (v,) = merge_chords([p], [sig[:, None]], 0.0, 0.005)
    assert np.array_equal(q, p) and np.array_equal(v[:, 0], sig)


def test_the_written_file_follows_the_path_within_the_tolerance_with_fewer_moves():
    p, sig = spiral()
    texts = {}
    for tol in (0.0, 0.02):
        buf = io.StringIO()
        stats = write_gcode([p], [sig], _with(PROFILE, chord_tolerance_mm=tol), buf, center=False)
        texts[tol] = (buf.getvalue(), stats)
    fine, merged = texts[0.0][1], texts[0.02][1]
    assert merged["moves_per_s"] < fine["moves_per_s"] / 3
    moves = [m for m in parse(texts[0.02][0]).moves if m.extruding and m.layer == 1]
    ends = np.array([moves[0].start[:2]] + [m.end[:2] for m in moves])
    assert point_polyline_distance(p, ends).max() <= 0.02 + 2e-3      # + 1 um rounding


def test_framing_bytes_match_the_wire_frames():
    for lines in (500, 1234, 20000):
        wire = sum(len(frame(n, "G1")) - len("G1\n") for n in range(1, lines + 1))
        assert framing_bytes(lines) == pytest.approx(wire / lines, abs=0.35)


def test_link_capacity_and_feed_percent():
    assert link_moves_per_s(115200, 30 * 1000, 1000) == pytest.approx(
        11520 / (30 + framing_bytes(1000)))
    assert feed_percent(100, 200) == 100
    assert feed_percent(200, 200) == int(100 * LINK_SHARE)


def test_a_file_the_link_cannot_carry_is_reported_with_what_to_change():
    p, sig = spiral()
    slow = dataclasses.replace(_with(PROFILE, chord_tolerance_mm=0.0),
                               serial=dataclasses.replace(PROFILE.serial, baud=2400))
    stats = write_gcode([p], [sig], slow, io.StringIO(), center=False)
    assert stats["moves_per_s"] > LINK_SHARE * stats["link_moves_per_s"]
    assert stats["feed_percent"] < 100 and stats["link_baud"] == 2400
    (problem,) = link_problems(stats, slow)
    assert problem["code"] == "gcode.link_too_slow"
    assert "serial.baud: " in problem["fix"] and "speeds_mm_s.print" in problem["fix"]
    fast = write_gcode([p], [sig], PROFILE, io.StringIO(), center=False)
    assert fast["feed_percent"] == 100 and link_problems(fast, PROFILE) == []


@pytest.mark.parametrize("baud", [2400, 2000000])
def test_a_job_the_link_cannot_carry_prints_slower_and_says_so(tmp_path, baud):
    # The simulated wire runs fast whatever baud the host believes the printer has.
    with pty_simulator() as (sim, port):
        _feed_said(tmp_path, sim, port, baud)


def _feed_said(tmp_path, sim, port, baud):
    d = in_process_daemon(tmp_path, 0, port=port, baud=baud)
    try:
        write_dome(d.config.drop_dir / "dome.npy")
        deadline = time.monotonic() + 120
        job = None
        while job is None or job["state"] not in (J.PRINTING, J.DONE, J.FAILED):
            assert time.monotonic() < deadline, "the job never started"
            d.tick()
            time.sleep(0.02)
            job = (d.store.list() or [None])[0]
        gcode = d.printing.gcode(job)
        feed = job_feed(gcode, baud)
        first = sim.commands()
        first = [c for c in first if not c.startswith(("M105", "M155", "M110", "M115"))][0]
        assert first == "M220 S%d" % feed.percent
        said = " ".join(e["message"] for e in d.store.events(job["id"]))
        if baud == 2400:
            assert feed.percent < 100 and "feed slowed to %d %%" % feed.percent in said
        else:
            assert feed.percent == 100 and "slowed" not in said
    finally:
        d.shutdown()
