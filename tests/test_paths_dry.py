"""Hops over printed paths move dry: where a join inside a trace runs over another path
the nozzle moves on without extruding; short stretches stay as they are."""

import numpy as np
import pytest

from pipeline.paths.dry import dry_figures, finish
from pipeline.paths.links import HOP, path_samples

PW = 0.5


def _line(a, b, n=41):
    return np.linspace(a, b, n)


def _hop_trace(hop_y, printed):
    """Two upright paths joined at their feet by a hop along ``y = hop_y``, from x = 2
    to x = 8, with the paths ``printed`` (list of (k, 2)) beside it. Returns (traces,
    shrink, samples of every path)."""
    a = _line((2.0, 5.0), (2.0, hop_y))
    b = _line((8.0, hop_y), (8.0, 5.0))
    trace = np.vstack([a, b])
    sigma = np.concatenate([np.full(len(a) - 1, 0.2), [HOP], np.full(len(b) - 1, 0.3)])
    traces = [trace] + printed
    tsig = [sigma] + [np.full(len(p) - 1, 0.25) for p in printed]
    return traces, tsig, path_samples([a, b] + printed, PW)


def _finished(hop_y, printed):
    traces, tsig, samples = _hop_trace(hop_y, printed)
    return finish(traces, tsig, *samples, PW)


def _dry_length(trace, dry):
    step = np.linalg.norm(np.diff(trace, axis=0), axis=1)
    return float(step[dry].sum())


def test_a_hop_along_a_printed_path_moves_dry():
    # The hop runs 6 mm at 0.2 mm from a printed path: closer than half a width.
    traces, tsig, dry, hops, over = _finished(0.2, [_line((0.0, 0.0), (10.0, 0.0))])
    assert len(hops) == 1 and over == pytest.approx([6.0], abs=PW / 4)
    assert _dry_length(traces[0], dry[0]) == pytest.approx(6.0, abs=1e-9)
    # The dry stretch is the hop's own line, with the mean shrink of the paths it joins.
    assert np.all(np.isfinite(tsig[0])) and np.allclose(tsig[0][dry[0]], 0.25)
    assert not dry[1].any()
    assert dry_figures(traces, dry) == {"dry_mm": pytest.approx(6.0), "dry_stretches": 1}


def test_a_hop_over_bare_sheet_is_extruded():
    traces, tsig, dry, hops, over = _finished(0.6, [_line((0.0, 0.0), (10.0, 0.0))])
    assert len(hops) == 1 and not dry[0].any() and over == pytest.approx([0.0])
    assert len(traces[0]) == 82 and np.nanmax(np.abs(tsig[0] - 0.25)) <= 0.05


def test_crossing_one_bead_is_too_short_to_stop_for():
    a = _line((5.0, 5.0), (5.0, 1.0))
    b = _line((5.0, -1.0), (5.0, -5.0))
    q = _line((0.0, 0.0), (10.0, 0.0))
    trace = np.vstack([a, b])
    sigma = np.concatenate([np.full(40, 0.2), [HOP], np.full(40, 0.2)])
    traces, tsig, dry, _, _ = finish([trace, q], [sigma, np.full(40, 0.2)],
                                  *path_samples([a, b, q], PW), PW)
    assert not dry[0].any() and np.allclose(tsig[0], 0.2)


def test_a_short_bare_gap_between_dry_stretches_moves_dry_too():
    # The printed path under the hop is broken by a gap of 0.6 mm (bare for about 0.1
    # mm of the hop): one dry stretch. A gap of 3 mm is printed: two.
    short = [_line((0.0, 0.0), (4.7, 0.0)), _line((5.3, 0.0), (10.0, 0.0))]
    traces, _, dry, _, _ = _finished(0.2, short)
    assert dry_figures(traces, dry)["dry_stretches"] == 1
    assert _dry_length(traces[0], dry[0]) == pytest.approx(6.0, abs=1e-9)
    wide = [_line((0.0, 0.0), (3.5, 0.0)), _line((6.5, 0.0), (10.0, 0.0))]
    traces, _, dry, _, _ = _finished(0.2, wide)
    assert dry_figures(traces, dry)["dry_stretches"] == 2
    assert 6.0 - 3.0 - PW <= _dry_length(traces[0], dry[0]) < 6.0 - 2.0


def test_a_join_is_never_merged_into_the_segments_beside_it():
    """Collinear segments of one shrink merge; a join's (``HOP``) stays a segment of its
    own, and the shrink of the runs beside it stays known."""
    from pipeline.paths.isoline import merge_collinear
    p = _line((0.0, 0.0), (10.0, 0.0), n=11)
    sigma = np.concatenate([np.full(4, 0.2), [HOP], np.full(5, 0.3)])
    q, s = merge_collinear(p, sigma, 2.0, 0.005)
    assert np.allclose(q[:, 0], [0.0, 4.0, 5.0, 10.0])
    assert np.allclose(s[[0, 2]], [0.2, 0.3]) and np.isnan(s[1])
