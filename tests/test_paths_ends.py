"""Cutting back path ends that run into other paths."""

import numpy as np

from pipeline.paths.ends import retract_ends

PW = 0.5


def _line(a, b, n):
    return np.linspace(a, b, n)


def test_an_end_running_into_a_path_is_cut_back_to_the_reach():
    """A piece ending a fifth of a width from another path's side stops where it keeps
    0.8 widths away; the path it ran into, and the piece's shrink, are kept."""
    wall = (_line((-5.0, 0.0), (5.0, 0.0), 21), np.full(20, 0.1), False)
    stub = (_line((0.0, 4.0), (0.0, 0.1), 40), np.linspace(0.2, 0.3, 39), False)
    out = retract_ends([wall, stub], PW)
    assert len(out) == 2 and np.array_equal(out[0][0], wall[0])
    p, sg, closed = out[1]
    assert not closed and len(sg) == len(p) - 1
    assert np.allclose(p[0], (0.0, 4.0))
    assert 0.8 * PW <= p[-1][1] <= 0.8 * PW + PW / 4
    assert np.array_equal(sg, stub[1][:len(sg)])


def test_of_two_ends_crowding_each_other_the_shorter_path_gives_way():
    """Two pieces in line whose ends face each other a fifth of a width apart: only the
    shorter is cut back, so the gap is not opened from both sides."""
    long_ = (_line((-6.0, 0.0), (0.0, 0.0), 40), np.full(39, 0.1), False)
    short = (_line((3.0, 0.0), (0.1, 0.0), 30), np.full(29, 0.1), False)
    out = retract_ends([long_, short], PW)
    assert np.array_equal(out[0][0], long_[0])
    assert 0.8 * PW <= out[1][0][-1][0] <= 0.8 * PW + PW / 4


def test_closed_paths_and_uncrowded_ends_are_kept_whole():
    ring = np.c_[np.cos(np.linspace(0, 2 * np.pi, 60, endpoint=False)),
                 np.sin(np.linspace(0, 2 * np.pi, 60, endpoint=False))] * 3
    chains = [(ring, np.full(60, 0.1), True),
              (_line((-1.0, 1.2), (1.0, 1.2), 10), np.full(9, 0.1), False)]
    out = retract_ends(chains, PW)
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(out, chains))


def test_an_end_running_alongside_a_path_is_cut_back_further_than_a_width():
    """A piece whose last 2.4 widths run a fifth of a width beside another path loses
    all of them, not only the first width."""
    wall = (_line((-5.0, 0.0), (5.0, 0.0), 21), np.full(20, 0.1), False)
    stub = (np.vstack([_line((0.0, 3.0), (0.0, 0.1), 30), _line((0.1, 0.1), (1.0, 0.1), 10)]),
            np.full(39, 0.2), False)
    p = retract_ends([wall, stub], PW)[1][0]
    assert abs(p[-1][0]) < 1e-9 and 0.8 * PW <= p[-1][1] <= 0.8 * PW + PW / 4
