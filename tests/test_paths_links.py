"""Joining stripe pieces by hops that print over no other path, and the report's measure
of the hops that do (``hop_overprint_mm``)."""

import numpy as np
import shapely

from pipeline.paths.bridges import bridge_rings
from pipeline.paths.links import join_ends, merge_joined, path_samples
from pipeline.paths.stats import hop_figures

PW = 0.5


def _sheet():
    sheet = shapely.box(-1, -1, 11, 2)
    shapely.prepare(sheet)
    return sheet


def _line(y, x0, x1):
    p = np.c_[np.linspace(x0, x1, 11), np.full(11, y)]
    return (p, np.full(10, 0.2), False)


def _joins(chains):
    samples, label, tree = path_samples([p for p, _, _ in chains], PW)
    return join_ends(chains, PW, 4 * PW, _sheet(), samples, label, tree)


def test_pieces_broken_across_a_bare_gap_run_on_as_one_path():
    # Three paths a width apart, each broken by the same 1.2 mm gap (a singular spot).
    chains = [_line(y, x0, x1) for y in (0.0, PW, 2 * PW) for x0, x1 in ((0, 4.4), (5.6, 10))]
    joins = _joins(chains)
    pairs = {tuple(sorted(j)) for j in joins.tolist()}
    # End 1 of piece 2k (its right end) meets end 0 of piece 2k + 1 across the gap.
    assert {(4 * k + 1, 4 * k + 2) for k in range(3)} <= pairs
    # The rest turn over at the sheet's edge, a width apart: two rows close into a ring
    # beside the third, and bridged into it they make one path.
    merged, hops = merge_joined(chains, joins)
    assert len(hops) == 5 and sorted(c for _, _, c in merged) == [False, True]
    (p, sg, closed), = bridge_rings(merged, PW)[0]
    assert not closed and len(sg) == len(p) - 1


def test_a_hop_that_would_cross_another_path_is_not_taken():
    # Ends (4.4, 0) and (5.6, 2 PW) face each other across the middle path.
    chains = [_line(0.0, 0, 4.4), _line(2 * PW, 5.6, 10), _line(PW, 0, 10)]
    pairs = {tuple(sorted(j)) for j in _joins(chains).tolist()}
    assert (1, 2) not in pairs and pairs        # the U-turns at the edge are taken


def test_hop_overprint_counts_only_the_length_over_a_third_path():
    paths = [_line(y, 0, 10)[0] for y in (0.0, PW, 2 * PW)]
    samples, label, tree = path_samples(paths, PW)
    beside = hop_figures(np.array([[[10, 0], [10, PW]]]), samples, label, tree, PW)
    across = hop_figures(np.array([[[10, 0], [10, 2 * PW]]]), samples, label, tree, PW)
    assert beside == {"hop_mm": PW, "hop_overprint_mm": 0.0, "hop_overprint_own_mm": 0.0}
    # Over the middle path for the width of its bead.
    assert across["hop_mm"] == 2 * PW
    assert abs(across["hop_overprint_mm"] - PW) <= PW / 4
    assert across["hop_overprint_own_mm"] == 0.0


def test_a_hop_back_along_its_own_path_prints_it_twice():
    """Leaving a path's end the hop may touch that path; running back along it, beyond
    a path width from the end, it prints it twice, and the join measures that too."""
    paths = [_line(y, 0, 10)[0] for y in (0.0, PW, 2 * PW)]
    samples, label, tree = path_samples(paths, PW)
    back = hop_figures(np.array([[[10, 0], [5, 0.1]]]), samples, label, tree, PW)
    assert back["hop_overprint_mm"] == 0.0
    # From 10 - PW + PW / 2 back to 5: within half a width of samples beyond the end's.
    assert abs(back["hop_overprint_own_mm"] - (5 - 0.5 * PW)) <= PW / 4


def _random_hops(seed):
    """300 random hops over 20 parallel paths half a millimetre apart: (a, b, own, the
    paths' samples, labels and tree)."""
    from pipeline.paths import links
    rng = np.random.default_rng(seed)
    paths = [np.c_[np.linspace(0, 40, 81), np.full(81, y)] for y in np.arange(0, 10, 0.5)]
    a = rng.uniform(0, 40, (300, 2)) * [1, 0.25]
    return (a, a + rng.normal(0, 2, (300, 2)), np.full(300, -1)) + links.path_samples(paths, 0.5)


def _count_asked(monkeypatch):
    """The number of points asked of the KD-tree, call by call, from now on: a list."""
    from pipeline.paths import links
    asked = []
    near = links._near_another

    def counted(q, *rest):
        asked.append(len(q))
        return near(q, *rest)
    monkeypatch.setattr(links, "_near_another", counted)
    return asked


def test_many_hops_are_measured_in_chunks_alike(monkeypatch):
    """Hops measured a chunk at a time (as on a real tile) give what all at once gives."""
    from pipeline.paths import links
    a, b, own, samples, label, tree = _random_hops(4)
    whole = links.over_others(a, b, own, own, samples, label, tree, 0.5)
    monkeypatch.setattr(links, "_CHUNK_POINTS", 50)
    assert np.allclose(links.over_others(a, b, own, own, samples, label, tree, 0.5), whole)
    assert whole.sum() > 0


def test_a_hop_over_others_beyond_the_limit_is_not_measured_further(monkeypatch):
    """Within the limit every hop's over-print is the full measure; beyond it, only some
    length above the limit, from fewer samples asked."""
    from pipeline.paths import links
    a, b, own, samples, label, tree = _random_hops(5)
    whole = links.over_others(a, b, own, own, samples, label, tree, 0.5)
    asked = _count_asked(monkeypatch)
    capped = links.over_others(a, b, own, own, samples, label, tree, 0.5, limit=1.0)
    within = whole <= 1.0
    assert within.any() and (~within).any()
    assert np.array_equal(capped[within], whole[within])
    assert (capped[~within] > 1.0).all()
    n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / 0.125), 1).sum()
    assert sum(asked) < n


def test_the_over_print_is_that_of_every_sample_asked_though_fewer_are(monkeypatch):
    """Neighbours of a sample found near another path are counted without being asked;
    the figure is still that of asking every sample: within half a width of another
    path's sample, or with sixteen samples within it."""
    from pipeline.paths import links
    a, b, _, samples, label, tree = _random_hops(6)
    own_a, own_b = label[tree.query(a)[1]], label[tree.query(b)[1]]
    end_a, end_b = 2 * own_a, 2 * own_b
    asked = _count_asked(monkeypatch)
    got = links.over_others(a, b, end_a, end_b, samples, label, tree, 0.5)
    want, total = [], 0
    for p, q, oa, ob in zip(a, b, own_a, own_b):
        n = max(int(np.ceil(np.linalg.norm(q - p) / 0.125)), 1)
        pts = p + (q - p) * ((np.arange(n) + 0.5) / n)[:, None]
        hits = tree.query_ball_point(pts, 0.25)
        bad = [len(k) >= 16 or any(label[j] not in (oa, ob) for j in k) for k in hits]
        want.append(sum(bad) * np.linalg.norm(q - p) / n)
        total += n
    assert np.allclose(got, want) and np.sum(want) > 0
    assert sum(asked) < 0.8 * total


def test_a_hop_over_another_path_within_the_budget_is_taken():
    # Ends (4.4, 0) and (4.4, 2 PW) face each other across a closed path (no ends).
    ring = np.array([[3.0, PW], [10.0, PW], [10.0, 1.1 * PW], [3.0, 1.1 * PW]])
    chains = [_line(0.0, 0, 4.4), _line(2 * PW, 2.2, 4.4), (ring, np.full(4, 0.2), True)]
    samples, label, tree = path_samples([p for p, _, _ in chains], PW)
    none = join_ends(chains, PW, 4 * PW, _sheet(), samples, label, tree)
    some = join_ends(chains, PW, 4 * PW, _sheet(), samples, label, tree, over_mm=2 * PW)
    assert (1, 3) not in {tuple(sorted(j)) for j in none.tolist()}
    assert (1, 3) in {tuple(sorted(j)) for j in some.tolist()}


def test_the_dear_hop_test_is_asked_only_of_joins_still_possible_and_changes_nothing():
    """Joins chosen with the over-print test asked lazily are those chosen with it asked
    of every candidate up front, and far fewer candidates are asked."""
    from pipeline.paths.links import _greedy
    rng = np.random.default_rng(1)
    n_chains, h = 300, 5000
    ea = rng.integers(0, 2 * n_chains, h)
    eb = rng.integers(0, 2 * n_chains, h)
    keep = ea // 2 != eb // 2
    ea, eb = ea[keep], eb[keep]
    cost = np.round(rng.uniform(0, 4, len(ea)), 1)         # ties, kept in order
    good = rng.uniform(size=len(ea)) >= 0.3
    asked = []

    def allowed(k):
        asked.append(len(k))
        return good[k]

    lazy = _greedy(ea, eb, cost, allowed)
    # Every candidate asked up front, cheapest first (ties in order), as plainly as it
    # can be written.
    used, upfront = set(), []
    for k in np.argsort(cost, kind="stable"):
        x, y = int(ea[k]), int(eb[k])
        if good[k] and x not in used and y not in used:
            used.update((x, y))
            upfront.append((x, y))
    assert lazy.tolist() == [list(j) for j in upfront] and len(lazy) > 100
    assert sum(asked) < len(ea) / 2


def test_a_short_join_in_the_wrong_place_does_not_break_a_serpentine():
    # Four paths a width apart whose right ends alternate 0.2 mm in and out along the
    # sheet's edge; their left ends lie too far apart to join. The shortest join, the
    # two middle ends, would leave the outer two ends loose (joining them would cross
    # the middle paths); joined in outer pairs, no right end is left loose.
    sheet = shapely.box(-10, -1, 11, 2)
    shapely.prepare(sheet)
    chains = []
    for k in range(4):
        x1 = 10.2 if k in (0, 3) else 10.0
        p = np.c_[np.linspace(-3 * k, x1, 21), np.full(21, 0.5 * k)]
        chains.append((p, np.full(20, 0.2), False))
    samples, label, tree = path_samples([p for p, _, _ in chains], PW)
    joins = join_ends(chains, PW, 4 * PW, sheet, samples, label, tree)
    assert {tuple(j) for j in joins.tolist()} == {(1, 3), (5, 7)}
    merged, hops = merge_joined(chains, joins)
    assert len(merged) == 2 and len(hops) == 2


def test_two_short_joins_in_the_wrong_places_do_not_break_a_serpentine():
    # Six paths a width apart; the four middle right ends lie flush, the outer two 0.3 mm
    # out. Shortest first joins 1-2 and 3-4 and strands the outer ends; only moving both
    # joins at once (0-1, 2-3, 4-5: a path of three hops through two joins) strands none.
    sheet = shapely.box(-20, -1, 11, 3.5)
    shapely.prepare(sheet)
    chains = []
    for k, x1 in enumerate((10.3, 10.0, 10.0, 10.0, 10.0, 10.3)):
        p = np.c_[np.linspace(-3 * k, x1, 21), np.full(21, 0.5 * k)]
        chains.append((p, np.full(20, 0.2), False))
    samples, label, tree = path_samples([p for p, _, _ in chains], PW)
    joins = join_ends(chains, PW, 4 * PW, sheet, samples, label, tree)
    assert {tuple(j) for j in joins.tolist()} == {(1, 3), (5, 7), (9, 11)}
    merged, _ = merge_joined(chains, joins)
    assert len(merged) == 3


def test_an_end_whose_nearest_ends_are_all_taken_is_offered_every_end_within_reach(
        monkeypatch):
    # Two rows of nine dashes, 1.5 mm long with 0.5 mm gaps, 16.5 mm apart end to end.
    # Each row's last end has its sixteen nearest ends in its own row, all joined across
    # the gaps (the hops along a row run over its dashes, beyond the budget); the other
    # row's first end, 16.5 mm off, is the seventeenth nearest, but within reach.
    from pipeline.paths import links
    monkeypatch.setattr(links, "NEAREST", 16)
    sheet = shapely.box(-1, -1, 53, 1)
    shapely.prepare(sheet)
    chains = [_line(0.0, x0 + 2 * k, x0 + 2 * k + 1.5) for x0 in (0.0, 34.0) for k in range(9)]
    samples, label, tree = path_samples([p for p, _, _ in chains], PW)
    joins = join_ends(chains, PW, 20.0, sheet, samples, label, tree, over_mm=PW)
    pairs = {tuple(j) for j in joins.tolist()}
    across_gaps = {(2 * c + 1, 2 * c + 2) for c in range(18) if c != 8 and c != 17}
    assert pairs == across_gaps | {(17, 18)}
