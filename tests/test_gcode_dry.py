"""Dry moves inside a trace: no E, no retraction, the layer's Z, and never merged into
the extruded moves beside them (chords or arcs)."""

import dataclasses
import io
import math

import numpy as np
import pytest

from gcode_parser import parse
from pipeline.gcode.writer import GcodeSettings, write_gcode
from pipeline.profiles.profile import load_profile

BASE = load_profile("generic-0.5mm")


def _profile(**toolpath):
    return dataclasses.replace(BASE, toolpath=dataclasses.replace(BASE.toolpath, **toolpath))


def _write(traces, sigmas, profile, **kw):
    buf = io.StringIO()
    stats = write_gcode(traces, sigmas, profile, buf, name="dry", **kw)
    return parse(buf.getvalue()), stats, buf.getvalue()


def _end_line(text):
    """The line number (1-based) where the profile's end G-code starts."""
    return text.split("\n").index("; hostd end") + 1


def _straight():
    """One straight trace of 60 segments of 0.5 mm along x, segments 20-39 dry."""
    pts = np.c_[np.linspace(0.0, 30.0, 61), np.zeros(61)]
    dry = np.zeros(60, bool)
    dry[20:40] = True
    return [pts], [np.full(60, 0.2)], [dry]


def _ring(r=20.0, n=400):
    a = np.linspace(0.0, 2 * np.pi, n + 1)
    dry = np.zeros(n, bool)
    dry[n // 3:n // 2] = True
    return [np.c_[r * np.cos(a), r * np.sin(a)]], [np.full(n, 0.2)], [dry]


def _layer(parsed, text, layer=1):
    """The layer's moves inside traces (the traces are centred on the bed): not the
    travel between them (G0), nor the end G-code's."""
    end = _end_line(text)
    return [m for m in parsed.moves if m.layer == layer and m.code in (1, 2, 3)
            and m.xy_length() > 0 and m.line_no < end]


def _x(m, start=False):
    """A move's end (or start) along the straight trace, mm from its first point."""
    return (m.start if start else m.end)[0] - BASE.bed_mm[0] / 2 + 15.0


def test_dry_segments_move_without_extruding_and_without_retracting():
    traces, sigmas, dry = _straight()
    parsed, stats, text = _write(traces, sigmas, _profile(chord_tolerance_mm=0.0), dry=dry)
    _, wet_stats, _ = _write(traces, sigmas, _profile(chord_tolerance_mm=0.0))
    moves = _layer(parsed, text)
    centre = np.array([0.5 * (_x(m, True) + _x(m)) for m in moves])
    idle = np.array([not m.extruding for m in moves])
    # The dry stretch (x from 10 to 20 mm) is moved without E, the rest is extruded.
    assert np.array_equal(idle, (centre > 10.0) & (centre < 20.0))
    # At the layer's height, in one trace: no travel, retraction or lift between.
    z = {round(m.end[2], 4) for m in moves}
    assert len(z) == 1 and stats["travel_moves"] == wet_stats["travel_moves"]
    assert stats["filament_mm"] == pytest.approx(
        wet_stats["filament_mm"] * 40 / 60, rel=1e-3)


def test_chords_never_merge_across_a_dry_stretch():
    traces, sigmas, dry = _straight()
    parsed, _, text = _write(traces, sigmas, _profile(chord_tolerance_mm=0.05), dry=dry)
    moves = _layer(parsed, text)
    # The collinear segments merge into three moves: extruded, dry, extruded.
    x = [round(_x(m), 3) for m in moves]
    assert x == [10.0, 20.0, 30.0]
    assert [m.extruding for m in moves] == [True, False, True]


def test_arcs_never_span_a_dry_stretch():
    traces, sigmas, dry = _ring()
    parsed, _, text = _write(traces, sigmas, _profile(arc_tolerance_mm=0.02), dry=dry)
    moves = _layer(parsed, text)
    assert any(m.code in (2, 3) for m in moves)
    a = np.linspace(0.0, 2 * np.pi, 401)
    for k in (400 // 3, 400 // 2):
        at = np.array([20 * math.cos(a[k]), 20 * math.sin(a[k])]) + np.array(BASE.bed_mm) / 2
        ends = np.array([m.end[:2] for m in moves])
        assert np.min(np.linalg.norm(ends - at, axis=1)) < 1e-3
    idle = [m for m in moves if not m.extruding]
    length = sum(m.xy_length() for m in idle)
    assert length == pytest.approx(2 * math.pi * 20 * (200 - 133) / 400, rel=0.01)


def test_the_upper_layers_own_paths_move_dry_too():
    traces, sigmas, dry = _straight()
    parsed, _, text = _write(traces, sigmas, _profile(chord_tolerance_mm=0.0),
                          upper=(traces, sigmas, None, dry))
    n = BASE.layers
    for layer in range(1, n + 1):
        idle = sum(not m.extruding for m in _layer(parsed, text, layer))
        # The lower half prints the paths with no dry flags; the upper half with them.
        assert idle == (20 if layer > n - n // 2 else 0), layer


def test_dry_moves_run_at_the_travel_speed_and_the_estimate_knows_it():
    traces, sigmas, dry = _straight()
    profile = _profile(chord_tolerance_mm=0.0)
    parsed, stats, text = _write(traces, sigmas, profile, dry=dry)
    _, wet_stats, _ = _write(traces, sigmas, profile)
    settings = GcodeSettings.from_profile(BASE)
    for layer in (1, 2):
        speed = settings.first_layer_mm_s if layer == 1 else settings.print_mm_s
        moves = _layer(parsed, text, layer)
        assert {m.f for m in moves if not m.extruding} == {settings.travel_mm_s * 60}
        assert {m.f for m in moves if m.extruding} == {speed * 60}
    # A feed word only where the feed changes: at the trace's start and both dry ends.
    lines = text.split("\n")
    first = lines[lines.index(";LAYER:0"):lines.index(";LAYER:1")]
    first = [ln for ln in first if ln.startswith("G1 X")]
    assert len(first) == 60 and sum(" F" in ln for ln in first) == 3
    # 10 mm of the 30 at 150 mm/s instead of 50 (30 on the first layer), per layer.
    saved = 10.0 / settings.print_mm_s - 10.0 / settings.travel_mm_s
    saved_first = 10.0 / settings.first_layer_mm_s - 10.0 / settings.travel_mm_s
    expected = (settings.layers - 1) * saved + saved_first
    assert wet_stats["estimated_print_s"] - stats["estimated_print_s"] == pytest.approx(
        expected, rel=0.05)
    # The link sees 60 moves in 20 mm at print speed and 10 at travel speed.
    assert stats["moves_per_s"] == pytest.approx(
        60 / (20.0 / settings.print_mm_s + 10.0 / settings.travel_mm_s), rel=1e-3)
