"""G-code with a thickness per layer (a bilayer): each layer's Z is the sum of the
thicknesses below it and its own, and each layer extrudes its own thickness."""

import io

import numpy as np
import pytest

from gcode_parser import parse
from pipeline.errors import PlanError
from pipeline.gcode.writer import GcodeSettings, write_thickness_gcode
from pipeline.profiles.profile import load_profile

PROFILE = load_profile("generic-0.5mm")


def _job(columns, arcs=0.0):
    """Three straight traces of 20 segments; thickness per segment and layer from
    ``columns`` ((layers,) mm, the same along every trace)."""
    settings = GcodeSettings.from_profile(PROFILE, layers=len(columns), arc_tolerance_mm=arcs)
    traces = [np.c_[np.linspace(0, 20, 21), np.full(21, 1.0 + y)] for y in (0.0, 0.5, 1.0)]
    thetas = [np.tile(np.asarray(columns, float), (20, 1)) for _ in traces]
    buf = io.StringIO()
    stats = write_thickness_gcode(traces, thetas, settings, buf, name="bilayer")
    return parse(buf.getvalue()), stats, settings


@pytest.mark.parametrize("arcs", [0.0, 0.02])
def test_each_layer_sits_on_the_sum_of_the_thicknesses_below(arcs):
    columns = [0.15, 0.15, 0.15, 0.30, 0.30, 0.30]
    parsed, stats, s = _job(columns, arcs)
    tops = np.cumsum(columns)
    for layer in range(1, 7):
        zs = {round(m.end[2], 3) for m in parsed.layer_moves(layer) if m.extruding}
        assert zs == {round(tops[layer - 1], 3)}, (layer, zs)
    # Each layer pushes the filament its own thickness needs: E = L * t * w / A.
    area = s.filament_area_mm2
    for layer in (1, 6):
        e = sum(m.e for m in parsed.layer_moves(layer) if m.extruding)
        want = 3 * 20.0 * columns[layer - 1] * s.path_width_mm / area
        assert e == pytest.approx(want, rel=1e-3)
    assert float(parsed.header["MAXZ"]) == pytest.approx(tops[-1])
    assert stats["thickness_mm"] == {"min": 0.15, "max": 0.30}


def test_equal_layers_given_per_layer_match_one_thickness_for_all():
    parsed_a, stats_a, _ = _job([0.2] * 6)
    settings = GcodeSettings.from_profile(PROFILE, layers=6)
    traces = [np.c_[np.linspace(0, 20, 21), np.full(21, 1.0 + y)] for y in (0.0, 0.5, 1.0)]
    buf = io.StringIO()
    write_thickness_gcode(traces, [np.full(20, 0.2)] * 3, settings, buf, name="bilayer")
    parsed_b = parse(buf.getvalue())
    assert [(m.end, round(m.e, 5)) for m in parsed_a.moves] == \
        [(m.end, round(m.e, 5)) for m in parsed_b.moves]


def test_a_column_count_that_is_neither_one_nor_the_layers_is_refused():
    settings = GcodeSettings.from_profile(PROFILE, layers=6)
    with pytest.raises(PlanError) as err:
        write_thickness_gcode([np.c_[[0.0, 1.0], [0.0, 0.0]]], [np.full((1, 4), 0.2)],
                              settings, io.StringIO())
    assert err.value.code == "gcode.bad_input"


def test_a_bilayer_prints_its_lower_layers_at_the_larger_shrink():
    """delta > 0: the lower half of the layers shrinks by sigma + delta / 2, so it is
    printed thinner than the upper half (thinner layers shrink more)."""
    from pipeline.gcode.writer import write_gcode
    trace = [np.c_[np.linspace(0, 20, 21), np.full(21, 1.0)]]
    buf = io.StringIO()
    write_gcode(trace, [np.full(20, 0.2)], PROFILE, buf, deltas=[np.full(20, 0.08)])
    parsed = parse(buf.getvalue())
    height = {}
    for layer in range(1, PROFILE.layers + 1):
        zs = sorted({round(m.end[2], 3) for m in parsed.layer_moves(layer) if m.extruding})
        height[layer] = zs[0]
    steps = np.diff([0.0] + [height[k] for k in sorted(height)])
    lower, upper = steps[:PROFILE.layers // 2], steps[-(PROFILE.layers // 2):]
    assert np.all(lower < upper)
    theta_lo = PROFILE.shrink_curve.theta(np.array([0.24]))[0][0]
    theta_hi = PROFILE.shrink_curve.theta(np.array([0.16]))[0][0]
    assert lower[0] == pytest.approx(theta_lo, abs=1e-3)
    assert upper[0] == pytest.approx(theta_hi, abs=1e-3)


def test_crossed_layer_groups_print_their_own_paths_each_on_the_layers_below():
    """The lower half of the layers prints the lower group's paths (along x), the upper
    half the upper group's (along y); every upper move sits on the lower layers'
    thickness at its own point plus its own, and the file counts both groups."""
    from pipeline.gcode.writer import write_gcode
    xs = np.linspace(0, 20, 21)
    lower = [np.c_[xs, np.full(21, y)] for y in (0.0, 10.0, 20.0)]
    upper = [np.c_[np.full(21, x), xs] for x in (0.0, 10.0, 20.0, 5.0)]
    sig = lambda traces, s: [np.full(len(t) - 1, s) for t in traces]  # noqa: E731
    buf = io.StringIO()
    stats = write_gcode(lower, sig(lower, 0.2), PROFILE, buf, deltas=sig(lower, 0.08),
                        upper=(upper, sig(upper, 0.2), sig(upper, 0.08)))
    parsed = parse(buf.getvalue())
    half = PROFILE.layers // 2
    theta_lo = PROFILE.shrink_curve.theta(np.array([0.24]))[0][0]
    theta_hi = PROFILE.shrink_curve.theta(np.array([0.16]))[0][0]
    for layer in range(1, PROFILE.layers + 1):
        moves = [m for m in parsed.layer_moves(layer) if m.extruding]
        along_x = all(m.start[1] == pytest.approx(m.end[1]) for m in moves)
        along_y = all(m.start[0] == pytest.approx(m.end[0]) for m in moves)
        assert (along_x, along_y) == ((True, False) if layer <= half else (False, True)), layer
        want = (theta_lo * min(layer, half) + theta_hi * max(layer - half, 0))
        zs = np.array([m.end[2] for m in moves])
        assert np.ptp(zs) == 0 and zs[0] == pytest.approx(want, abs=0.001 * layer), layer
    assert stats["traces"] == 3 and stats["upper_traces"] == 4
    assert stats["travel_moves"] == 3 * half + 4 * (PROFILE.layers - half)
    assert stats["extrusion_moves"] == len([m for m in parsed.moves
                                            if m.extruding and m.layer is not None])
    # Filament: each group's own length times its own layers' thickness.
    area = PROFILE.filament_mm ** 2 * np.pi / 4
    want = (3 * 20 * theta_lo * half + 4 * 20 * theta_hi * half) * PROFILE.path_width_mm / area
    assert stats["filament_mm"] == pytest.approx(want, rel=1e-3)
