"""G-code of the reference shapes' real tool paths, read back with our own parser."""

import io

import numpy as np
import pytest

from conftest import reference_toolpaths
from gcode_parser import parse
from pipeline.gcode.writer import write_gcode
from pipeline.profiles.profile import load_profile


@pytest.fixture(scope="module")
def profile():
    return load_profile("generic-0.5mm")


@pytest.mark.parametrize("name", ["dome", "saddle", "starfish"])
def test_reference_shape_gcode_reads_back_as_planned(name, profile):
    mesh, flat, tp = reference_toolpaths(name)
    out = io.StringIO()
    stats = write_gcode(tp.traces, tp.sigma, profile, out, name=name)
    g = parse(out.getvalue())
    moves = [m for m in g.moves if m.extruding and m.layer is not None]
    assert moves, "no extruding moves"
    lo, hi = profile.thickness_mm.min, profile.thickness_mm.max
    layer = np.array([m.layer for m in moves])
    z = np.array([m.end[2] for m in moves])
    theta = z / layer
    # Every extruding move's thickness in the profile's range; Z of layer k = k x thickness.
    assert theta.min() >= lo - 1e-3 and theta.max() <= hi + 1e-3
    first = {}
    for m, th in zip(moves, theta):
        first.setdefault((round(m.end[0], 3), round(m.end[1], 3)), []).append(th)
    same = [np.ptp(v) for v in first.values() if len(v) == profile.layers]
    assert len(same) > 0.5 * len(first) and max(same) < 2e-3
    # E matches the volume: length x thickness x width / filament area.
    area = np.pi * profile.filament_mm ** 2 / 4
    expect = np.array([m.xy_length() * th * profile.path_width_mm / area
                       for m, th in zip(moves, theta)])
    got = np.array([m.e for m in moves])
    assert np.allclose(got, expect, rtol=2e-3, atol=2e-4)
    # All moves on the bed; counts as reported.
    xy = np.array([m.end[:2] for m in g.moves if m.layer is not None])
    assert (xy >= 0).all() and (xy[:, 0] <= profile.bed_mm[0]).all() \
        and (xy[:, 1] <= profile.bed_mm[1]).all()
    runs = sum(len(g.runs(layer=k)) for k in range(1, profile.layers + 1))
    assert runs == profile.layers * tp.info["traces"]
    assert sum(len(g.travels(layer=k)) for k in range(1, profile.layers + 1)) >= \
        profile.layers * tp.info["travel_moves"]
    assert stats["traces"] == tp.info["traces"] and stats["layers"] == profile.layers
    assert stats["lines"] == out.getvalue().count("\n")
