"""Stripe-pattern tool paths along a direction field: spacing, coverage, direction, and
each segment's shrink from the triangle it crosses."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import Delaunay

from pipeline.linalg import factor_spd
from pipeline.paths import stripes
from pipeline.paths.sheet import Sheet
from pipeline.paths.stripes import plan_stripes, stripe_toolpaths

WIDTH = 0.5


def _disk(radius=30.0, h=1.0, seed=0):
    rng = np.random.default_rng(seed)
    pts = [np.zeros((1, 2))]
    for r in np.arange(h, radius + 1e-9, h):
        k = max(int(2 * np.pi * r / h), 3)
        a = np.linspace(0, 2 * np.pi, k, endpoint=False) + rng.uniform(0, 1)
        pts.append(np.c_[r * np.cos(a), r * np.sin(a)])
    pts = np.vstack(pts)
    faces = Delaunay(pts).simplices
    P = pts[faces]
    cross = ((P[:, 1, 0] - P[:, 0, 0]) * (P[:, 2, 1] - P[:, 0, 1])
             - (P[:, 1, 1] - P[:, 0, 1]) * (P[:, 2, 0] - P[:, 0, 0]))
    faces[cross < 0] = faces[cross < 0][:, [0, 2, 1]]
    return pts, faces


def _field(kind, c):
    if kind == "circles":          # one +1 singular point: concentric paths
        d = np.stack([-c[:, 1], c[:, 0]], 1)
    elif kind == "turn":           # turns by 90 degrees across the sheet
        a = (c[:, 0] + 30) / 60 * np.pi / 2
        d = np.stack([np.cos(a), np.sin(a)], 1)
    elif kind == "parallel":       # no curl: straight paths from edge to edge
        d = np.tile([1.0, 0.0], (len(c), 1))
    elif kind == "monkey":         # a monkey saddle's: paths fan out, forking everywhere
        a = -2 * np.arctan2(c[:, 1], c[:, 0])
        d = np.stack([np.cos(a), np.sin(a)], 1)
    else:                          # two +1/2 singular points at (-10, 0) and (10, 0)
        z = ((c[:, 0] - 10) + 1j * c[:, 1]) * ((c[:, 0] + 10) + 1j * c[:, 1])
        d = np.stack([np.cos(np.angle(z) / 2), np.sin(np.angle(z) / 2)], 1)
    return d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]


def _plan(kind, **options):
    xy, faces = _disk()
    d = _field(kind, xy[faces].mean(axis=1))
    return stripe_toolpaths(xy, faces, d, np.full(len(faces), 0.2), WIDTH, **options).info


@pytest.mark.parametrize("kind", ["circles", "turn", "two_half"])
def test_paths_are_a_path_width_apart(kind):
    s = _plan(kind)["spacing_mm"]
    assert 0.8 * WIDTH <= s["p05"] and s["p95"] <= 1.2 * WIDTH, s


@pytest.mark.parametrize("kind", ["circles", "turn"])
def test_paths_cover_the_sheet(kind):
    info = _plan(kind)
    assert info["coverage"] > 0.95 and info["overlap"] < 0.05, info


def test_paths_cover_a_sheet_with_two_half_singularities():
    assert _plan("two_half")["coverage"] > 0.95


def test_the_trace_ends_inside_the_sheet_bound_the_traces_from_below():
    """Straight paths end on the sheet's edge only, where hops join them into one trace;
    paths that turn (a field with curl) fork inside, and a fork's end is joined only by
    a hop that prints over other paths: the more of that the hops may print, the fewer
    ends are left inside, and the traces are at least half as many as those."""
    parallel = _plan("parallel")
    assert parallel["ends_inside"] == 0 and parallel["traces"] == 1
    for kind in ("turn", "monkey"):
        tight, free = _plan(kind, over_factor=2.0), _plan(kind, over_factor=8.0)
        assert tight["ends_inside"] > 10 and free["ends_inside"] < tight["ends_inside"]
        assert free["hop_overprint_mm"] + free["hop_overprint_own_mm"] > (
            tight["hop_overprint_mm"] + tight["hop_overprint_own_mm"])
        for info in (tight, free):
            assert 2 * info["traces"] >= info["ends_inside"]

def test_segments_chain_into_polylines_and_rings_in_a_fixed_order():
    """An open polyline is walked from its lower free end, a ring from end 0 of its
    lowest segment; open ones first (end ``e`` is end ``e % 2`` of segment ``e // 2``)."""
    keys = np.array([[1, 2], [5, 3], [0, 1], [3, 4], [4, 5], [7, 8]])
    got = [(list(np.asarray(steps)), closed) for steps, closed in stripes.chain(keys)]
    assert got == [([1, 5], False), ([10], False), ([2, 6, 8], True)]
    assert stripes.chain(np.zeros((0, 2), np.int64)) == []

def test_a_piece_shorter_than_a_path_width_is_not_printed(monkeypatch):
    """A stripe grazing a triangle at the outline leaves a piece a fraction of a path
    width long: printed, it would be a trace of its own, a blob; it is left out."""
    xy, faces = _disk()
    path = np.c_[np.linspace(-10, 10, 41), np.zeros(41)]
    stub = np.array([[5.0, 8.0], [5.2, 8.0]])
    pieces = [(path, np.full(40, 0.1), False), (stub, np.full(1, 0.1), False)]
    monkeypatch.setattr(stripes, "plan_stripes", lambda *a, **k: stripes.Stripes(
        pieces, np.zeros(len(faces), np.int8), 0.0, [np.zeros(40, int), np.zeros(1, int)]))
    tp = stripe_toolpaths(xy, faces, np.tile([1.0, 0.0], (len(faces), 1)),
                          np.full(len(faces), 0.1), WIDTH, retract=0)
    assert len(tp.traces) == 1 and np.allclose(tp.traces[0][[0, -1]], path[[0, -1]])

def _drawn(xy, faces, normal, width):
    phase, X, solved = stripes.stripe_phase_at_width(Sheet(xy, faces), normal, width,
                                                     stripes.WIDTH_TOL)
    u, bare = stripes.corner_phases(xy, faces, phase, X, solved)
    return stripes.drawn_spacing(xy, faces, u, bare == 0)


def test_fanning_paths_are_drawn_a_path_width_apart(monkeypatch):
    xy, faces = _disk()
    d = _field("monkey", xy[faces].mean(axis=1))
    normal = np.stack([-d[:, 1], d[:, 0]], 1)
    assert abs(_drawn(xy, faces, normal, WIDTH) / WIDTH - 1) <= stripes.WIDTH_TOL
    corrected = _plan("monkey")
    # As asked, the cheapest pattern draws them closer, and prints more of it twice.
    monkeypatch.setattr(stripes, "WIDTH_TOL", 10.0)
    assert _drawn(xy, faces, normal, WIDTH) < 0.99 * WIDTH
    assert _plan("monkey")["overlap"] > corrected["overlap"] + 0.003
    assert corrected["coverage"] > 0.95


def _waves(refine=True, retract=stripes.REACH):
    """A disk of triangles 2.5 path widths a side whose print direction swings by half a
    radian to either side every 6 mm, as on real terrain: the stripes fork in most
    triangles of some patches."""
    xy, faces = _disk(radius=20.0, h=1.25)
    c = xy[faces].mean(axis=1)
    a = 0.5 * np.sin(2 * np.pi * c[:, 0] / 6) * np.cos(2 * np.pi * c[:, 1] / 6)
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    return stripe_toolpaths(xy, faces, d, np.full(len(faces), 0.2), WIDTH, refine=refine,
                            retract=retract).info


def test_finer_triangles_cover_a_field_that_turns_faster_than_the_triangles():
    """The phase carried to finer triangles leaves each fork a patch a sixteenth of a
    triangle: coverage 0.89 on the layout's triangles, 0.96 on the finer ones."""
    coarse, fine = _waves(refine=False), _waves()
    assert coarse["coverage"] < 0.95 < fine["coverage"], (coarse["coverage"], fine["coverage"])
    assert fine["pathless_mm2"] < 0.1 * coarse["pathless_mm2"]
    assert fine["overlap"] < 0.02 and fine["spacing_mm"]["p05"] >= 0.8 * WIDTH, fine


def test_path_ends_that_run_into_other_paths_are_cut_back():
    """Where the stripes fork, the paths converge on the fork: cut back, their ends
    overlap other paths less and the paths keep nearer a path width apart."""
    cut, kept = _waves(), _waves(retract=0)
    assert cut["overlap"] < 0.5 * kept["overlap"], (cut["overlap"], kept["overlap"])
    assert kept["spacing_mm"]["p05"] < 0.8 * WIDTH <= cut["spacing_mm"]["p05"]


def test_concentric_paths_follow_the_direction():
    info = _plan("circles")
    assert info["direction_angle_deg"]["p95"] < 5.0 and info["traces"] <= 5


def test_each_segment_carries_the_shrink_of_its_triangle():
    xy, faces = _disk()
    c = xy[faces].mean(axis=1)
    sigma = 0.05 + 0.25 * (c[:, 0] + 30) / 60
    drawn = plan_stripes(xy, faces, _field("turn", c), sigma, WIDTH)
    tri = Delaunay(xy)                 # the same triangles, in the same order
    assert len(drawn.chains) > 50
    for (p, sg, closed), face in zip(drawn.chains, drawn.faces):
        q = np.vstack([p, p[:1]]) if closed else p
        f = tri.find_simplex((q[1:] + q[:-1]) / 2)
        # The shrink, and the triangle the direction angles compare the segment with.
        assert np.all(f >= 0) and np.array_equal(sg, sigma[f]) and np.array_equal(face, f)


def test_the_stripe_phase_is_the_same_every_run():
    """A fixed start, not a random one: a plan run twice gives the same paths."""
    xy, faces = _disk()
    d = _field("two_half", xy[faces].mean(axis=1))
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1)
    first, _ = stripes.stripe_phase(Sheet(xy, faces), normal, 0.48)
    again, _ = stripes.stripe_phase(Sheet(xy, faces), normal, 0.48)
    assert np.array_equal(first, again)


def test_the_smallest_eigenvector_of_a_nearly_degenerate_pair_is_found():
    rng = np.random.default_rng(3)
    n = 60
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    vals = np.r_[1.0, 1.0005, np.linspace(3.0, 50.0, n - 2)]
    mass = rng.uniform(0.5, 2.0, n)
    S = np.diag(np.sqrt(mass))
    A = S @ Q @ np.diag(vals) @ Q.T @ S            # A x = lambda M x has these eigenvalues
    x = stripes.smallest_eigenvector(sp.csr_matrix(A), mass, -1e-3)
    rayleigh = float(x @ A @ x) / float(x @ (mass * x))
    assert rayleigh == pytest.approx(1.0, rel=2e-3)


def _crowded(n=300, crowd=20, seed=4):
    """``A``, ``mass`` with the eigenvalues a dome's rings give: a smallest one, a
    ``crowd`` just above it, and the rest far off."""
    rng = np.random.default_rng(seed)
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    vals = np.r_[1.0, np.linspace(1.02, 1.1, crowd), np.linspace(3.0, 80.0, n - crowd - 1)]
    mass = rng.uniform(0.5, 2.0, n)
    S = np.diag(np.sqrt(mass))
    return sp.csr_matrix(S @ Q @ np.diag(vals) @ Q.T @ S), mass


def test_a_crowd_of_small_eigenvalues_costs_few_solves(monkeypatch):
    """Inverse iteration creeps through eigenvalues crowded above the smallest, each solve
    dividing their share by only 1.02; the Ritz vector of the solves' Krylov basis is
    within the tolerance after a fraction of them, and is the answer."""
    A, mass = _crowded()
    shift, tol = -1e-6, 1e-2
    solves = []

    def counted(*args, **kwargs):
        lu = factor_spd(*args, **kwargs)

        class Counted:
            def solve(self, b):
                solves.append(1)
                return lu.solve(b)
        return Counted()
    monkeypatch.setattr(stripes, "factor_spd", counted)
    x = stripes.smallest_eigenvector(A, mass, shift, tol=tol)
    lam = float(x @ A @ x) / float(x @ (mass * x))
    r = A @ x - lam * mass * x
    assert np.sqrt(r @ (r / mass)) / np.sqrt(x @ (mass * x)) <= 1.01 * tol * lam
    # Inverse iteration from the same start, to the same tolerance.
    lu = factor_spd(A - shift * sp.diags(mass))
    y = np.random.default_rng(0).standard_normal(len(mass))
    for plain in range(1, 101):
        y = lu.solve(mass * y)
        y /= np.sqrt(y @ (mass * y))
        mu = float(y @ A @ y)
        if np.linalg.norm((A @ y - mu * mass * y) / np.sqrt(mass)) <= tol * mu:
            break
    assert len(solves) * 3 <= plain, (len(solves), plain)


def test_a_problem_smaller_than_the_basis_is_solved_exactly():
    """A sheet of a few vertices has fewer unknowns than the solves allowed: the basis
    spans the whole space, and its Ritz vector is the eigenvector itself."""
    A, mass = _crowded(n=12, crowd=2)
    x = stripes.smallest_eigenvector(A, mass, -1e-6, tol=1e-9)
    assert np.all(np.isfinite(x))
    assert float(x @ A @ x) / float(x @ (mass * x)) == pytest.approx(1.0, rel=1e-9)


def test_joining_stripe_pieces_leaves_fewer_traces_within_the_overprint_budget():
    """Pieces that end facing each other across bare sheet run on as one path: fewer
    traces than the pieces left apart, and fewer the more a hop may print over other
    paths; with no hop over paths allowed, no hop prints over one, and the paths are
    the same in all three."""
    xy, faces = _disk()
    d = _field("two_half", xy[faces].mean(axis=1))
    sigma = np.full(len(faces), 0.2)
    # Joined at the edge, an end leaves a path's tail out: the paths would differ.
    apart = stripe_toolpaths(xy, faces, d, sigma, WIDTH, join_factor=0.0,
                             rim_tail_factor=0.0).info
    joined = stripe_toolpaths(xy, faces, d, sigma, WIDTH, rim_tail_factor=0.0).info
    tight = stripe_toolpaths(xy, faces, d, sigma, WIDTH, over_factor=0.0,
                             rim_tail_factor=0.0).info
    assert joined["traces"] <= tight["traces"] < apart["traces"]
    assert tight["hop_overprint_mm"] == 0.0 < joined["hop_overprint_mm"]
    for key in ("coverage", "overlap", "spacing_mm"):
        assert joined[key] == apart[key] == tight[key]


def test_pathless_triangles_are_told_apart_by_cause():
    """Around a +1/2 singular point the line field turns over (a branch); a field that
    only turns has no singular point, and its paths end only where the stripes fork
    (the turn has curl, so their spacing cannot stay even without)."""
    two_half, turn = _plan("two_half"), _plan("turn")
    assert two_half["branch_triangles"] > 0
    assert turn["branch_triangles"] == 0 and turn["fork_triangles"] > 0
    for info in (two_half, turn):
        assert info["fork_triangles"] + info["branch_triangles"] == info["pathless_triangles"]


def test_stripe_pieces_join_across_a_wider_reach_with_a_little_over_print():
    """Hops of up to nine widths that run over other paths for at most eight widths join
    more pieces than hops of four widths over none; the paths themselves are unchanged."""
    xy, faces = _disk()
    d = _field("two_half", xy[faces].mean(axis=1))
    sigma = np.full(len(faces), 0.2)
    strict = stripe_toolpaths(xy, faces, d, sigma, WIDTH, join_factor=4.0, over_factor=0.0).info
    wide = stripe_toolpaths(xy, faces, d, sigma, WIDTH).info
    assert wide["traces"] < strict["traces"], (wide["traces"], strict["traces"])
    for key in ("coverage", "overlap", "spacing_mm"):
        assert wide[key] == strict[key]


def test_one_sheet_serves_every_direction_of_a_plan():
    """A plan draws stripes along three fields on one layout and keeps what no direction
    changes (edges, weights, the energy's pattern, the split triangles) between them:
    each set is the one a sheet of its own draws."""
    xy, faces = _disk()
    c = xy[faces].mean(axis=1)
    sigma = np.full(len(faces), 0.1)
    sheet = Sheet(xy, faces)
    for name in ("two_half", "turn", "circles"):
        d = _field(name, c)
        shared = stripe_toolpaths(xy, faces, d, sigma, WIDTH, sheet=sheet)
        own = stripe_toolpaths(xy, faces, d, sigma, WIDTH)
        assert len(shared.traces) == len(own.traces)
        assert all(np.array_equal(a, b) for a, b in zip(shared.traces, own.traces))
    A, _ = stripes.stripe_matrix(sheet, stripes.vertex_line_field(sheet, d), WIDTH)
    assert abs(A - A.T).max() < 1e-12


def _off_centre(**options):
    """Paths round a singular point 15 mm off the middle of the 30 mm disk: rings round
    it, and arcs the edge cuts that graze it on the far side."""
    xy, faces = _disk()
    c = xy[faces].mean(axis=1)
    d = np.stack([-c[:, 1], c[:, 0] - 15.0], 1)
    d /= np.linalg.norm(d, axis=1)[:, None]
    return stripe_toolpaths(xy, faces, d, np.full(len(faces), 0.2), WIDTH, **options).info


def test_rings_beside_other_paths_are_bridged_into_them(monkeypatch):
    """Rings nest inside the arcs the sheet's edge cuts: bridged into the paths beside
    them they need no trace of their own (with hops of four widths: longer ones join
    this sheet's arcs into a trace or two either way)."""
    from pipeline.paths import bridges
    bridged = _off_centre(rim_tail_factor=0.0, join_factor=4.0)
    monkeypatch.setattr(bridges, "bridge_rings", lambda chains, pw: (chains, np.zeros((0, 2, 2))))
    alone = _off_centre(rim_tail_factor=0.0, join_factor=4.0)
    assert bridged["ring_bridges"] > 20 and alone["ring_bridges"] == 0
    assert bridged["traces"] < alone["traces"]
    assert bridged["coverage"] == alone["coverage"]


def test_an_end_at_the_edge_joins_the_path_beside_it():
    """Where the paths graze the edge, an end there joins the path a width in, whose
    tail along the edge is left out (and not counted as covered). Hops of four widths
    leave ends at the edge that longer ones would join across the sheet."""
    joined, kept = _off_centre(join_factor=4.0), _off_centre(join_factor=4.0, rim_tail_factor=0.0)
    assert joined["rim_tails"] >= 1 and kept["rim_tails"] == 0
    assert joined["traces"] < kept["traces"]
    bare = joined["rim_tail_mm"] * WIDTH / (np.pi * 30.0 ** 2)
    assert 0.2 * bare < kept["coverage"] - joined["coverage"] < 2 * bare
