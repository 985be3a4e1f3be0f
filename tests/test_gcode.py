"""G-code (paper 6.4): thickness per move, Z = theta * layer, E from volume, bed, header, arcs.

Everything is checked by parsing the written text with our own parser
(tests/gcode_parser.py), not by trusting the writer's stats.
"""

import dataclasses
import io
import math
import re

import numpy as np
import pytest

from gcode_parser import parse, point_polyline_distance, sample_move
from pipeline.errors import PlanError
from pipeline.gcode.writer import GcodeSettings, write_gcode
from pipeline.gcode.numfmt import format_fixed
from pipeline.profiles.profile import load_profile

# Chords kept as given: these tests follow each segment into the file (merging has its own).
PROFILE = dataclasses.replace(
    load_profile("generic-0.5mm"),
    toolpath=dataclasses.replace(load_profile("generic-0.5mm").toolpath, chord_tolerance_mm=0.0))


def rings(n_rings=12, spacing=0.48, r0=3.0, seg_mm=0.25, wobble=0.02):
    """Concentric circles, sigma falling outward with a wobble along each circle."""
    traces, sigmas = [], []
    for i in range(n_rings):
        r = r0 + i * spacing
        n = max(int(2 * np.pi * r / seg_mm), 12)
        a = np.linspace(0.0, 2 * np.pi, n + 1)
        traces.append(np.c_[r * np.cos(a), r * np.sin(a)])
        mid = (a[:-1] + a[1:]) / 2
        sigmas.append(0.3 * (1 - i / n_rings) + wobble * np.sin(3 * mid))
    return traces, sigmas


def zigzag(width=20.0, height=10.0, spacing=0.48, seg_mm=1.0):
    """One boustrophedon trace of axis-parallel paths, sigma varying along x."""
    pts = []
    for j, y in enumerate(np.arange(0.0, height + 1e-9, spacing)):
        xs = np.arange(0.0, width + 1e-9, seg_mm)
        xs = xs if j % 2 == 0 else xs[::-1]
        pts.extend((x, y) for x in xs)
    pts = np.array(pts)
    mid = (pts[:-1] + pts[1:]) / 2
    return [pts], [0.05 + 0.25 * mid[:, 0] / width]


def write(traces, sigmas, profile=PROFILE, **kw):
    buf = io.StringIO()
    stats = write_gcode(traces, sigmas, profile, buf, name="test", **kw)
    return buf.getvalue(), stats


def settings(**kw):
    return GcodeSettings.from_profile(PROFILE, **kw)


@pytest.fixture(scope="module")
def ring_job():
    traces, sigmas = rings()
    text, stats = write(traces, sigmas)
    return traces, sigmas, text, stats, parse(text)


@pytest.fixture(scope="module")
def zig_job():
    traces, sigmas = zigzag()
    text, stats = write(traces, sigmas)
    return traces, sigmas, text, stats, parse(text)


JOBS = ["ring_job", "zig_job"]


def _extruding(parsed, layer):
    return [m for m in parsed.layer_moves(layer) if m.extruding]


@pytest.mark.parametrize("job", JOBS)
def test_every_move_thickness_within_profile_limits(job, request):
    *_, parsed = request.getfixturevalue(job)
    lo, hi = PROFILE.thickness_mm.min, PROFILE.thickness_mm.max
    seen = 0
    for layer in range(1, PROFILE.layers + 1):
        for m in _extruding(parsed, layer):
            theta = m.end[2] / layer
            assert lo - 1e-9 <= theta <= hi + 1e-9, (m.line_no, theta)
            seen += 1
    assert seen > 0


@pytest.mark.parametrize("job", JOBS)
def test_z_of_layer_k_is_k_times_the_moves_thickness(job, request):
    _, sigmas, _, _, parsed = request.getfixturevalue(job)
    first = np.array([m.end[2] for m in _extruding(parsed, 1)])
    # Layer 1's Z is the thickness, and it is the shrink curve's theta for each segment.
    expected, _ = PROFILE.shrink_curve.theta(np.concatenate(sigmas))
    expected = np.clip(expected, PROFILE.thickness_mm.min, PROFILE.thickness_mm.max)
    assert len(first) == len(expected)
    np.testing.assert_allclose(first, expected, atol=0.5e-3 + 1e-9)
    assert np.ptp(first) > 0.05  # thickness really varies along and across the paths
    for layer in range(2, PROFILE.layers + 1):
        z = np.array([m.end[2] for m in _extruding(parsed, layer)])
        np.testing.assert_allclose(z, layer * first, rtol=0, atol=1e-9)


@pytest.mark.parametrize("job", JOBS)
def test_extrusion_matches_volume(job, request):
    *_, stats, parsed = request.getfixturevalue(job)
    area = math.pi * PROFILE.filament_mm ** 2 / 4
    w = PROFILE.path_width_mm
    total = 0.0
    for layer in range(1, PROFILE.layers + 1):
        moves = _extruding(parsed, layer)
        e = np.array([m.e for m in moves])
        vol = np.array([m.xy_length() * (m.end[2] / layer) * w / area for m in moves])
        # Each move is within 1e-3 relative plus E's last written digit ...
        assert np.all(np.abs(e - vol) <= 1e-3 * vol + 1.01e-5)
        # ... and rounding does not accumulate over the layer.
        assert abs(e.sum() - vol.sum()) <= 1e-3 * vol.sum()
        total += e.sum()
    assert total == pytest.approx(stats["filament_mm"], rel=1e-3)


@pytest.mark.parametrize("job", JOBS)
def test_all_moves_on_the_bed(job, request):
    *_, parsed = request.getfixturevalue(job)
    xy = np.array([m.end[:2] for m in parsed.moves])
    bx, by = PROFILE.bed_mm
    assert xy[:, 0].min() >= 0 and xy[:, 1].min() >= 0
    assert xy[:, 0].max() <= bx and xy[:, 1].max() <= by
    # and the part is centred on the bed
    part = np.array([m.end[:2] for m in parsed.moves if m.layer and m.extruding])
    np.testing.assert_allclose((part.min(0) + part.max(0)) / 2, [bx / 2, by / 2], atol=2e-3)


@pytest.mark.parametrize("job", JOBS)
def test_traces_and_travels_as_reported(job, request):
    traces, _, _, stats, parsed = request.getfixturevalue(job)
    assert stats["traces"] == len(traces)
    for layer in range(1, PROFILE.layers + 1):
        assert len(parsed.runs(layer)) == len(traces)
        assert len(parsed.travels(layer)) == len(traces)
    assert stats["travel_moves"] == sum(len(parsed.travels(k)) for k in range(1, 7))
    assert stats["lines"] == parsed.lines
    assert stats["layers"] == PROFILE.layers == len(parsed.layer_comments)


def test_travel_retracts_and_hops(ring_job):
    *_, parsed = ring_job
    hop = PROFILE.retraction.z_hop_mm
    r = PROFILE.retraction.length_mm
    moves = [m for m in parsed.moves if m.layer]
    for i, m in enumerate(moves):
        if not m.travel:
            continue
        # Lifted above the printed surface by the hop while travelling ...
        printed_z = [p.end[2] for p in moves[:i] if p.extruding] or [0.0]
        assert m.start[2] >= printed_z[-1] + hop - 1e-9
        # ... and the filament is retracted (E net -length since the last extrusion).
        back = 0.0
        for p in reversed(moves[:i]):
            if p.extruding:
                break
            back += p.e
        assert back == pytest.approx(-r, abs=1e-9) or i == 0 or printed_z == [0.0]
    # every retraction is undone before printing (the start G-code left it retracted,
    # the end G-code retracts again)
    last = max(i for i, m in enumerate(moves) if m.extruding)
    assert sum(m.e for m in moves[:last] if not m.extruding) == pytest.approx(r, abs=1e-9)
    assert sum(m.e for m in moves[last + 1:]) < 0


def test_header_for_viewers(ring_job):
    *_, text, stats, parsed = ring_job
    h = parsed.header
    assert h["FLAVOR"] == "Marlin"
    assert int(h["TIME"]) == round(stats["estimated_print_s"]) > 0
    assert float(h["Filament used"].rstrip("m")) == pytest.approx(stats["filament_mm"] / 1000,
                                                                  rel=1e-4)
    assert int(h["LAYER_COUNT"]) == PROFILE.layers
    assert parsed.layer_comments == list(range(1, PROFILE.layers + 1))
    assert float(h["filament used [mm]"]) == pytest.approx(stats["filament_mm"], rel=1e-4)
    assert float(h["filament used [g]"]) == pytest.approx(stats["filament_g"], rel=1e-3)
    assert re.fullmatch(r"(\d+h )?\d+m \d+s", h["estimated printing time (normal mode)"])
    assert ";TYPE:" in text and ";generated by hostd " in text
    # the header comes before any motion
    assert text.index(";TIME:") < text.index("\nG1 ")
    # filament mass from volume and density
    grams = stats["filament_mm"] * math.pi * PROFILE.filament_mm ** 2 / 4 / 1000 * 1.24
    assert stats["filament_g"] == pytest.approx(grams, rel=1e-3)


def test_start_and_end_gcode_from_profile(ring_job):
    *_, text, _, _ = ring_job
    start = PROFILE.render_gcode("start")
    assert start.strip() in text and "{" not in text
    assert "M104 S215" in text and "M140 S60" in text
    assert text.index(start.strip()) < text.index(";LAYER:0")
    assert text.rstrip().index(PROFILE.render_gcode("end").strip()) > text.index(";LAYER:5")


def test_compact_numbers_and_modal_axes(zig_job):
    *_, text, stats, parsed = zig_job
    body = text[text.index(";LAYER:0"):]
    numbers = re.findall(r"(?<=[XYZEFIJ])-?\d+\.\d+", body)
    assert numbers and not [n for n in numbers if n.endswith("0")]
    assert not re.search(r"[XYZ]-?\d+\.\d{4}", body) and not re.search(r"E-?\d+\.\d{6}", body)
    g1 = [ln for ln in body.splitlines() if ln.startswith("G1 ") and " E" in ln and "X" in ln
          or ln.startswith("G1 Y")]
    # axis-parallel zig-zag: most moves name only the axis that changes
    assert sum(1 for ln in g1 if " Y" not in ln) > len(g1) / 2
    # F only where it changes: once per trace on the print moves
    extr = [ln for ln in body.splitlines() if ln.startswith("G1 ") and "E" in ln
            and ("X" in ln or "Y" in ln)]
    assert sum(" F" in ln for ln in extr) == stats["traces"] * PROFILE.layers


def test_format_fixed():
    assert list(format_fixed([12500, 3000, -50, 0, 1], 3, "X")) == ["X12.5", "X3", "X-0.05",
                                                                   "X0", "X0.001"]
    assert list(format_fixed([123456789], 5)) == ["1234.56789"]


def test_absolute_extrusion_same_amounts():
    traces, sigmas = rings(n_rings=4)
    rel = parse(write(traces, sigmas)[0])
    text, _ = write(traces, sigmas, settings(relative_e=False))
    ab = parse(text)
    assert "M82" in text and "G92 E" in text
    e_rel = [m.e for m in rel.moves if m.layer]
    e_abs = [m.e for m in ab.moves if m.layer]
    np.testing.assert_allclose(e_abs, e_rel, atol=1.01e-5)


def test_clamped_segments_counted():
    traces, sigmas = rings(n_rings=3, wobble=0.0)
    lo, hi = PROFILE.shrink_curve.sigma_range
    sigmas[0] = np.full_like(sigmas[0], hi + 0.1)  # more shrink than the thinnest layer gives
    sigmas[1][:5] = lo - 0.05
    _, stats = write(traces, sigmas)
    assert stats["clamped_segments"] == len(sigmas[0]) + 5
    assert stats["thickness_mm"]["min"] == pytest.approx(PROFILE.thickness_mm.min)
    assert stats["thickness_mm"]["max"] == pytest.approx(PROFILE.thickness_mm.max)


def test_off_bed_names_side_and_overhang():
    traces = [np.array([[0.0, 0.0], [230.0, 0.0], [230.0, 10.0]])]  # 230 mm on a 220 mm bed
    with pytest.raises(PlanError) as exc:
        write(traces, [np.full(2, 0.1)])
    assert exc.value.code == "gcode.off_bed"
    assert "5.00 mm past the left edge" in str(exc.value)
    assert "5.00 mm past the right edge" in str(exc.value)
    shifted = [np.array([[-3.0, 50.0], [100.0, 50.0]])]
    with pytest.raises(PlanError) as exc:
        write(shifted, [np.array([0.1])], center=False)
    assert exc.value.code == "gcode.off_bed" and "3.00 mm past the left edge" in str(exc.value)


def test_path_output_is_atomic(tmp_path):
    traces, sigmas = rings(n_rings=2)
    out = tmp_path / "a.gcode"
    stats = write_gcode(traces, sigmas, PROFILE, out)
    assert out.stat().st_size == stats["bytes"]
    assert not list(tmp_path.glob("*.part"))
    bad = tmp_path / "b.gcode"
    with pytest.raises(PlanError):
        write_gcode([t * 100 for t in traces], sigmas, PROFILE, bad)
    assert list(tmp_path.iterdir()) == [out]


def test_binary_file_object():
    traces, sigmas = rings(n_rings=2)
    buf = io.BytesIO()
    stats = write_gcode(traces, sigmas, PROFILE, buf)
    assert len(buf.getvalue()) == stats["bytes"]


def test_arcs_stay_within_tolerance_and_cut_lines():
    traces, sigmas = rings(n_rings=10, r0=5.0, wobble=0.0)
    tol = 0.02
    plain_text, plain = write(traces, sigmas)
    text, stats = write(traces, sigmas, settings(arc_tolerance_mm=tol))
    parsed = parse(text)
    assert stats["lines_without_arcs"] == plain["lines"]
    assert stats["lines"] < 0.3 * plain["lines"]
    arcs = [m for m in parsed.moves if m.code in (2, 3)]
    assert arcs and all(m.code == 3 for m in arcs)  # the rings run counter-clockwise
    # Every point along every printed move is within the tolerance of a ring.
    offset = np.array(PROFILE.bed_mm) / 2
    rings_xy = [t + offset for t in traces]
    layer1 = [m for m in parsed.moves if m.layer == 1 and m.extruding]
    radii = np.array([np.linalg.norm(t[0]) for t in traces])
    worst = 0.0
    for m in layer1:
        pts = sample_move(m)[:, :2]
        ring = np.argmin(np.abs(radii - np.linalg.norm(pts[0] - offset)))
        worst = max(worst, point_polyline_distance(pts, rings_xy[ring]).max())
    assert worst <= tol + 1e-3
    # E still matches volume on arcs, Z still layer * thickness.
    area = math.pi * PROFILE.filament_mm ** 2 / 4
    for m in (m for m in arcs if m.layer == 3):
        vol = m.xy_length() * (m.end[2] / 3) * PROFILE.path_width_mm / area
        assert abs(m.e - vol) <= 1e-3 * vol + 1.01e-5
    assert stats["filament_mm"] == pytest.approx(plain["filament_mm"], rel=2e-3)


def test_arcs_follow_varying_curvature_within_tolerance():
    # An ellipse: no single circle fits long stretches, so only a tolerance check
    # on every arc keeps the printed path on the polyline.
    a = np.linspace(0, 2 * np.pi, 801)
    ellipse = np.c_[40 * np.cos(a), 12 * np.sin(a)]
    sig = [np.full(800, 0.2)]
    tol = 0.01
    text, stats = write([ellipse], sig, settings(arc_tolerance_mm=tol))
    assert stats["lines"] < 0.5 * stats["lines_without_arcs"]
    parsed = parse(text)
    poly = ellipse + np.array(PROFILE.bed_mm) / 2
    layer1 = [m for m in parsed.moves if m.layer == 1 and m.extruding]
    worst = max(point_polyline_distance(sample_move(m, 0.02)[:, :2], poly, near_mm=1.0).max()
                for m in layer1 if m.code != 1)
    assert worst <= tol + 1e-3


def test_arcs_never_cross_a_thickness_jump():
    traces, sigmas = rings(n_rings=1, r0=20.0, wobble=0.0)
    n = len(sigmas[0])
    step = n // 3
    sigmas[0][step:] += 0.05  # a jump far above merge_sigma (0.005)
    text, stats = write(traces, sigmas, settings(arc_tolerance_mm=0.02))
    parsed = parse(text)
    layer1 = [m for m in parsed.moves if m.layer == 1 and m.extruding]
    assert any(m.code in (2, 3) for m in layer1)
    jump_xy = traces[0][step] + np.array(PROFILE.bed_mm) / 2
    ends = np.array([m.end[:2] for m in layer1])
    assert np.min(np.linalg.norm(ends - jump_xy, axis=1)) < 1e-3
    thick = [round(m.end[2], 3) for m in layer1]
    assert len(set(thick)) == 2


def test_zigzag_has_no_arcs():
    traces, sigmas = zigzag()
    _, stats = write(traces, sigmas, settings(arc_tolerance_mm=0.05))
    assert stats["arcs"] == 0 and stats["lines"] == stats["lines_without_arcs"]


def test_moves_per_second_reported(ring_job):
    traces, _, _, stats, _ = ring_job
    length = sum(np.linalg.norm(np.diff(t, axis=0), axis=1).sum() for t in traces)
    n = sum(len(t) - 1 for t in traces)
    assert stats["moves_per_s"] == pytest.approx(n / (length / PROFILE.speeds_mm_s.print),
                                                 rel=1e-2)
    assert stats["estimated_print_s"] > PROFILE.layers * length / PROFILE.speeds_mm_s.print
