"""Closed paths bridged into a neighbouring path: fewer traces, no end added, and the
rungs print where the stretches left out were."""

import numpy as np

from pipeline.paths.bridges import bridge_rings
from pipeline.paths.links import path_samples

PW = 0.5


def _ring(radius, k=400, centre=(0.0, 0.0)):
    a = np.linspace(0, 2 * np.pi, k, endpoint=False)
    p = np.c_[radius * np.cos(a), radius * np.sin(a)] + centre
    return (p, np.full(k, 0.2), True)


def _line(y, x0, x1, k=201):
    p = np.c_[np.linspace(x0, x1, k), np.full(k, y)]
    return (p, np.full(k - 1, 0.3), False)


def _box(x0, x1, y0, y1, step=0.1):
    """A closed rectangle, counter-clockwise from its lower left corner."""
    nx, ny = round((x1 - x0) / step), round((y1 - y0) / step)
    low = np.c_[np.linspace(x0, x1, nx + 1)[:-1], np.full(nx, y0)]
    right = np.c_[np.full(ny, x1), np.linspace(y0, y1, ny + 1)[:-1]]
    top = np.c_[np.linspace(x1, x0, nx + 1)[:-1], np.full(nx, y1)]
    left = np.c_[np.full(ny, x0), np.linspace(y1, y0, ny + 1)[:-1]]
    p = np.vstack([low, right, top, left])
    return (p, np.full(len(p), 0.2), True)


def _length(chain):
    p, _, closed = chain
    p = np.vstack([p, p[:1]]) if closed else p
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def test_nested_rings_become_one_ring():
    rings = [_ring(r) for r in (5.0, 5.0 + PW, 5.0 + 2 * PW)]
    merged, rungs = bridge_rings(rings, PW)
    assert len(merged) == 1 and merged[0][2]
    assert len(rungs) == 4
    # Each rung crosses from one ring to the next: a path width long, pointing outwards.
    assert np.allclose(np.linalg.norm(rungs[:, 1] - rungs[:, 0], axis=1), PW, atol=0.02)
    # A path width of each ring is left out at each bridge, and the rungs added.
    left_out = sum(map(_length, rings)) - _length(merged[0]) + 4 * PW
    assert 4 * PW * 0.9 < left_out < 4 * PW * 1.4
    # Every segment keeps a shrink; a rung takes its neighbours'.
    p, sg, _ = merged[0]
    assert len(sg) == len(p) and np.allclose(sg, 0.2)


def test_a_ring_beside_an_open_path_joins_it_and_keeps_its_two_ends():
    line = _line(0.0, 0.0, 20.0)
    ring = _box(5.0, 15.0, PW, PW + 3.0)
    merged, rungs = bridge_rings([line, ring], PW)
    assert len(merged) == 1 and not merged[0][2] and len(rungs) == 2
    p = merged[0][0]
    ends = {tuple(np.round(p[0], 6)), tuple(np.round(p[-1], 6))}
    assert ends == {(0.0, 0.0), (20.0, 0.0)}
    # The rungs stand where the ring's lower side runs beside the line.
    assert np.all((rungs[..., 1] > -1e-9) & (rungs[..., 1] < PW + 1e-9))
    assert np.all((rungs[..., 0] >= 5.0) & (rungs[..., 0] <= 15.0))


def test_open_paths_are_never_bridged_to_each_other():
    lines = [_line(y, 0.0, 20.0) for y in (0.0, PW, 2 * PW)]
    merged, rungs = bridge_rings(lines, PW)
    assert len(rungs) == 0 and all(a is b for a, b in zip(merged, lines))


def test_a_ring_between_two_open_paths_joins_only_one():
    # Bridged to both, the two would be one run through the ring and one left over:
    # the same two ends, a mess of rungs for nothing.
    below, above = _line(0.0, 0.0, 20.0), _line(3.0 + 2 * PW, 0.0, 20.0)
    ring = _box(5.0, 15.0, PW, PW + 3.0)
    merged, rungs = bridge_rings([below, ring, above], PW)
    assert len(rungs) == 2 and len(merged) == 2
    assert not any(c for _, _, c in merged)
    assert sorted(round(_length(m)) for m in merged) == [20, 20 + 26]


def test_a_ring_with_no_path_beside_it_is_left_alone():
    far = _ring(3.0, centre=(20.0, 0.0))
    line = _line(0.0, -5.0, 5.0)
    merged, rungs = bridge_rings([line, far], PW)
    assert len(rungs) == 0 and len(merged) == 2


def test_rungs_print_over_no_other_path():
    rings = [_ring(r) for r in np.arange(3.0, 6.0, PW)]
    merged, rungs = bridge_rings(rings, PW)
    assert len(merged) == 1 and len(rungs) == 2 * (len(rings) - 1)
    samples, label, tree = path_samples([np.vstack([p, p[:1]]) for p, _, _ in rings], PW)
    t = np.linspace(0.1, 0.9, 9)[None, :, None]
    along = rungs[:, :1] + t * (rungs[:, 1:] - rungs[:, :1])            # (r, 9, 2)
    _, end = tree.query(rungs.reshape(-1, 2))
    joined = label[end].reshape(-1, 2)
    near = tree.query_ball_point(along.reshape(-1, 2), 0.45 * PW)
    for k, found in enumerate(near):
        assert set(label[found].tolist()) <= set(joined[k // 9].tolist())
    # Each rung joins two rings side by side.
    assert np.all(np.abs(joined[:, 0] - joined[:, 1]) == 1)


def test_small_rings_between_rings_on_both_sides_are_bridged_outward():
    """Round a centre, each small ring lies a width from the rings on both sides, and
    along it the nearest of the two changes by turns; the bridges ask both, so the
    innermost rings join the ones outside them (the dome's centre once stood alone)."""
    rings = [_ring(r, k=int(80 * r)) for r in (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)]
    merged, rungs = bridge_rings(rings, PW)
    assert len(merged) == 1 and merged[0][2] and len(rungs) == 2 * (len(rings) - 1)


def test_a_piece_of_no_length_keeps_one_shrink():
    """Two bridges' stretches can meet at a point of a path, where round-off puts the
    piece between them a hair below zero length: it still has one shrink per segment."""
    from pipeline.paths.ends import _cut
    p = np.array([[0.0, 0.0], [2.0, 0.0], [4.0, 0.0]])
    at = np.array([0.0, 2.0, 4.0])
    piece, sg, closed = _cut(p, at, np.array([0.1, 0.3]), 2.0, 2.0 - 3e-13, p[1], p[1])
    assert len(piece) == 2 and len(sg) == 1 and not closed
