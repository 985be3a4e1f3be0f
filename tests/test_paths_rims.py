"""Ends at the sheet's edge joined to the path beside them, that path's tail along the
edge left out: paths meeting the edge at a slant end further apart than a hop reaches."""

import numpy as np
import shapely

from pipeline.paths.links import path_samples
from pipeline.paths.rims import join_at_rim, leave_slivers, printed_samples

PW = 0.5
ANGLE = np.radians(3.0)
EDGE = shapely.box(-5.0, 0.0, 40.0, 10.0)


def _slant(x_end, x0=0.0, k=120):
    """A path running down to the edge (y = 0) at a slant, ending at ``x_end``."""
    x = np.linspace(x0, x_end, k)
    return (np.c_[x, (x_end - x) * np.tan(ANGLE)], np.full(k - 1, 0.25), False)


def _two():
    # The second path lies a path width above the first, so it meets the edge
    # PW / sin(3 degrees) = 9.6 mm further on.
    return [_slant(10.0), _slant(10.0 + PW / np.sin(ANGLE))]


def test_an_end_at_the_edge_joins_the_path_beside_it_whose_tail_is_left_out():
    merged, hops, tails = join_at_rim(_two(), PW, EDGE.boundary, longest=40)
    assert len(merged) == 1 and len(hops) == 1 and len(tails) == 1
    # A U-turn straight up from the first path's end to the second path above it.
    (a, b), = hops
    assert np.allclose(sorted([a[1], b[1]]), [0.0, PW], atol=0.06)
    assert abs(a[0] - 10.0) < 0.1 and abs(b[0] - 10.0) < 0.1
    # The tail: the second path from above the first one's end to its own end.
    tail = tails[0]
    assert abs(np.linalg.norm(np.diff(tail, axis=0), axis=1).sum() - PW / np.sin(ANGLE)) < 0.2
    assert np.allclose(sorted([tail[0][0], tail[-1][0]]), [10.0, 10.0 + PW / np.sin(ANGLE)],
                       atol=0.1)
    # The path printed keeps both far ends (at x = 0) and every shrink; the U-turn is a
    # hop, its shrink settled when the traces are finished.
    p, sg, closed = merged[0]
    assert not closed and np.allclose(p[[0, -1], 0], 0.0)
    assert np.isnan(sg).sum() == 1 and np.allclose(sg[np.isfinite(sg)], 0.25)


def test_a_tail_longer_than_allowed_is_kept():
    # The tail is 9.6 mm, 19 path widths.
    merged, hops, tails = join_at_rim(_two(), PW, EDGE.boundary, longest=18)
    assert len(merged) == 2 and len(hops) == 0 and tails == []
    assert join_at_rim(_two(), PW, EDGE.boundary, longest=0)[2] == []


def test_a_tail_that_leaves_the_edge_is_kept():
    # The second path turns away from the edge before it ends: cutting it back would
    # leave bare sheet inside, not a sliver at the edge.
    first, second = _two()
    p = second[0].copy()
    p[p[:, 0] > 14.0, 1] += 3.0
    merged, hops, tails = join_at_rim([first, (p, second[1], False)], PW, EDGE.boundary, 40)
    assert len(merged) == 2 and tails == []


def test_ends_away_from_the_edge_are_left_to_the_hops():
    lifted = shapely.box(-5.0, -2.0, 40.0, 10.0).boundary      # the ends 2 mm inside
    merged, hops, tails = join_at_rim(_two(), PW, lifted, longest=40)
    assert len(merged) == 2 and tails == []


def test_the_samples_of_a_tail_left_out_are_told_apart():
    chains = _two()
    _, _, tails = join_at_rim(chains, PW, EDGE.boundary, longest=40)
    samples, label, tree = path_samples([p for p, _, _ in chains], PW)
    left, left_label, tree = printed_samples(samples, label, tree, tails, PW)
    # All of the first path's samples and the second path's up to x = 10.
    assert np.array_equal(left[left_label == 0], samples[label == 0])
    second = left[left_label == 1]
    assert second[:, 0].max() < 10.15 and len(second) > 0
    assert tree.n == len(left)


def test_a_path_left_out_whole_leaves_the_others_numbered_in_a_row():
    lines = [np.c_[np.linspace(0, 5, 11), np.full(11, y)] for y in (0.0, 1.0, 2.0)]
    samples, label, tree = path_samples(lines, PW)
    left, left_label, _ = printed_samples(samples, label, tree, [lines[1]], PW)
    assert sorted(set(left_label.tolist())) == [0, 1]
    assert np.array_equal(left[left_label == 1], samples[label == 2])


def _along(x0, x1, y, k=30):
    x = np.linspace(x0, x1, k)
    return (np.c_[x, np.full(k, y)], np.full(k - 1, 0.25), False)


def test_a_short_piece_along_the_edge_on_its_own_is_left_out():
    # A long path a few widths in, and beside it pieces along the edge (y = 0): one of
    # 3 mm hugging it (left out), one as short two widths further in, one hugging it for
    # longer than allowed, and a short one in the middle of the sheet.
    chains = [_along(-4.0, 39.0, 2.0, 200), _along(0.0, 3.0, 0.25), _along(5.0, 8.0, 0.25 + 2 * PW),
              _along(10.0, 30.0, 0.25), _along(12.0, 15.0, 5.0)]
    kept, slivers = leave_slivers(chains, PW, EDGE.boundary, longest=20)
    assert len(slivers) == 1 and np.allclose(slivers[0], chains[1][0])
    assert [c[0][0, 0] for c in kept] == [-4.0, 5.0, 10.0, 12.0]
    # Nothing is left out with the rim step off, nor the longest path.
    assert len(leave_slivers(chains, PW, EDGE.boundary, longest=0)[1]) == 0
    assert len(leave_slivers(chains[1:2], PW, EDGE.boundary, longest=20)[1]) == 0
