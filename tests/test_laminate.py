"""Two layers printed across the paths: a stack of layers, each shrinking along
its own direction, gives the sheet its metric and its natural curvature in both
directions; a terrain, which bends across its paths as much as along them, rests closer
with it, and its G-code prints those layers on paths of their own."""

import io

import numpy as np
import pytest

from gcode_parser import parse
from pipeline.input import shapes
from pipeline.layout.laminate import Laminate, across_laminate
from pipeline.profiles.profile import load_profile
from test_curvature_program import plan_layout, with_curvature

PROFILE = load_profile("generic-0.5mm")
D = np.array([[1.0, 0.0]])
ALONG = np.zeros(6, dtype=bool)
OUTER = np.array([True, False, False, False, False, True])


def test_two_equal_groups_along_the_paths_are_the_bilayer():
    """Three layers at 0.25 below three at 0.15, 1.5 mm thick: the bilayer's
    ``c * (s_bottom - s_top) / h`` along d, nothing across, mean shrink 0.2 along d."""
    lam = Laminate(layer_sigma=np.array([[0.25] * 3 + [0.15] * 3]), across=ALONG,
                   thickness_mm=np.array([1.5]))
    K = lam.curvature(D, c=1.5)[0]
    assert K[0, 0] == pytest.approx(1.5 * 0.10 / 1.5) and K[1, 1] == pytest.approx(0.0)
    assert np.allclose(lam.metric(D)[0], [[0.2, 0.0], [0.0, 0.0]])


def test_a_shrinking_first_layer_across_the_paths_curls_the_sheet_across_them():
    """The first layer, across d, shrinks by 0.1: the sheet curves up across d (a dome's
    sign), not along it, and shrinks a sixth of that across d."""
    s = np.array([[0.1, 0.0, 0.0, 0.0, 0.0, 0.0]])
    lam = Laminate(layer_sigma=s, across=OUTER, thickness_mm=np.array([1.5]))
    K = lam.curvature(D, c=1.5)[0]
    assert K[1, 1] > 0 and K[0, 0] == pytest.approx(0.0) and K[0, 1] == pytest.approx(0.0)
    # Lever of the first of six layers: 5 half layers below the middle.
    assert K[1, 1] == pytest.approx(6.0 / (36 * 1.5) * 5 * 0.1)
    assert lam.metric(D)[0] == pytest.approx(np.array([[0.0, 0.0], [0.0, 0.1 / 6]]))
    s_top = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.1]])
    top = Laminate(layer_sigma=s_top, across=OUTER, thickness_mm=np.array([1.5]))
    assert top.curvature(D, c=1.5)[0, 1, 1] == pytest.approx(-K[1, 1])


@pytest.mark.parametrize("twist", [0.0, 0.004])
def test_the_stack_programs_the_target_in_both_directions_and_keeps_the_metric_along_d(twist):
    """Four triangles with the target bending either way along and across d (at 45
    degrees in the layout), and twisting: the stack's curvature is the target's, its
    mean shrink the layout's along d with no shear, only the layer across on the concave
    side of the curvature across d shrinks, and the halves along d turn apart only for
    a twist."""
    d = np.tile([np.sqrt(0.5), np.sqrt(0.5)], (4, 1))
    e = np.stack([-d[:, 1], d[:, 0]], axis=1)
    k_dd = np.array([0.01, -0.01, 0.02, 0.0])
    k_ee = np.array([0.02, 0.02, -0.015, -0.01])
    K = (k_dd[:, None, None] * np.einsum("mi,mj->mij", d, d)
         + k_ee[:, None, None] * np.einsum("mi,mj->mij", e, e)
         + twist * (np.einsum("mi,mj->mij", d, e) + np.einsum("mi,mj->mij", e, d)))
    sigma = np.array([0.1, 0.12, 0.08, 0.1])
    lim = PROFILE.shrink_limits

    def layer_mm(s):
        return np.clip(PROFILE.shrink_curve.theta(np.asarray(s, float))[0],
                       PROFILE.thickness_mm.min, PROFILE.thickness_mm.max)
    lam = across_laminate(K, d, sigma, layer_mm, 6, lim.s_min, lim.s_max, c=1.5,
                          turn_max_deg=20.0)
    assert list(np.flatnonzero(lam.across) + 1) == [2, 5]
    assert np.allclose(lam.curvature(d, c=1.5), K, atol=2e-4)
    metric = lam.metric(d)
    assert np.allclose(np.einsum("mi,mij,mj->m", d, metric, d), sigma, atol=1e-4)
    # Turned halves keep the mean free of shear to first order in their turn.
    assert np.allclose(np.einsum("mi,mij,mj->m", d, metric, e), 0.0, atol=2e-4)
    s = lam.layer_sigma
    assert np.all((s[:, 1] > 0) == (k_ee > 0)) and np.all((s[:, 4] > 0) == (k_ee < 0))
    assert lam.turned == (twist > 0)
    assert set(lam.groups()) == ({"lower", "upper", "across"} if twist else {"lower", "across"})
    # The stack's thickness is the sum of the layers' printed for their shrink.
    assert np.allclose(lam.thickness_mm, layer_mm(s.ravel()).reshape(s.shape).sum(axis=1))


def test_the_layers_across_curl_with_their_own_constant():
    """The layers across carry ``c_across``, those along ``c``: doubling the one doubles
    the curvature across d and leaves it along d, and the other way round; without
    ``c_across`` both use ``c``."""
    s = np.array([[0.2, 0.15, 0.2, 0.1, 0.02, 0.1]])
    lam = Laminate(layer_sigma=s, across=np.array([False, True, False, False, True, False]),
                   thickness_mm=np.array([1.5]))
    base = lam.curvature(D, c=1.5, c_across=1.5)[0]
    assert np.allclose(lam.curvature(D, c=1.5)[0], base)
    assert base[0, 0] != 0 and base[1, 1] != 0
    twice_across = lam.curvature(D, c=1.5, c_across=3.0)[0]
    assert twice_across[1, 1] == pytest.approx(2 * base[1, 1])
    assert twice_across[0, 0] == pytest.approx(base[0, 0])
    twice_along = lam.curvature(D, c=3.0, c_across=1.5)[0]
    assert twice_along[0, 0] == pytest.approx(2 * base[0, 0])
    assert twice_along[1, 1] == pytest.approx(base[1, 1])


def test_a_stronger_constant_across_programs_the_same_curvature_with_less_shrink():
    """With ``c_across`` twice ``c`` the layers across shrink half as much above the
    least shrink for the same curvature across d, the layers along d as before, and the
    stack, modelled with both constants, still bends as the target."""
    d = np.tile([1.0, 0.0], (2, 1))
    K = np.array([np.diag([0.004, 0.006]), np.diag([-0.003, -0.004])])
    sigma = np.array([0.12, 0.1])
    lim = PROFILE.shrink_limits

    def layer_mm(s):
        return np.clip(PROFILE.shrink_curve.theta(np.asarray(s, float))[0],
                       PROFILE.thickness_mm.min, PROFILE.thickness_mm.max)
    same = across_laminate(K, d, sigma, layer_mm, 6, lim.s_min, lim.s_max, c=1.5)
    strong = across_laminate(K, d, sigma, layer_mm, 6, lim.s_min, lim.s_max, c=1.5,
                             c_across=3.0)
    assert np.allclose(strong.curvature(d, c=1.5, c_across=3.0), K, atol=2e-4)
    cross = np.flatnonzero(strong.across)
    more = same.layer_sigma[:, cross] - lim.s_min
    # The thickness follows the shrink, so half the shrink is only nearly half the curl.
    assert np.allclose(strong.layer_sigma[:, cross] - lim.s_min, more / 2, rtol=0.05,
                       atol=1e-6)
    assert np.allclose(strong.layer_sigma[:, ~strong.across], same.layer_sigma[:, ~same.across],
                       rtol=0.05)


def small_terrain():
    """A 60 x 45 mm terrain tile, 12.5 mm of relief, laid out as the plan does."""
    hf = shapes.terrain_tile(width_mm=60.0, depth_mm=45.0, height_mm=12.5)
    return (hf,) + plan_layout(hf)


def test_a_terrain_rests_closer_with_two_layers_across_the_paths():
    """A terrain bends across its paths about as much as along them: with two layers
    across, its sheet rests at least a third closer than the best sheet printed along d
    (the bilayer, or the twist), and the program says so; with ``across_layers: off``
    nothing is tried."""
    from pipeline.simulation.programmed import simulate_free
    hf, profile, mesh, flat = small_terrain()
    prog, sim = simulate_free(hf, mesh, flat, profile)
    tried = prog.across
    assert tried["kept"] and prog.laminate is not None
    assert sim.mean_displacement_mm == pytest.approx(tried["tried_mean_displacement_mm"])
    report = prog.report()["across"]
    assert report["layers"] == [2, profile.layers - 1] and report["sigma"]["max"] > 0
    off, sim_off = simulate_free(hf, mesh, flat, with_curvature(profile, across_layers="off"))
    assert off.across is None and off.laminate is None
    # Both were probed from the bilayer's rest.
    assert off.twist["along_mean_displacement_mm"] == pytest.approx(
        tried["before_mean_displacement_mm"])
    best_along = min(sim_off.mean_displacement_mm, tried["before_mean_displacement_mm"])
    assert sim.mean_displacement_mm < 0.67 * best_along


@pytest.mark.parametrize("layers", [(2, 5), (1, 6)])
def test_the_layers_across_print_their_own_paths_each_on_the_layers_below(layers):
    """The layers along print paths along x, those across paths along y; every move's Z
    is the sum of the thicknesses below it at its own point, and the file counts both
    sets of paths once."""
    from pipeline.gcode.writer import write_laminate_gcode
    xs = np.linspace(0, 20, 21)
    along = [np.c_[xs, np.full(21, y)] for y in (0.0, 10.0, 20.0)]
    across = [np.c_[np.full(21, x), xs] for x in (0.0, 10.0, 20.0, 5.0)]
    shrink = np.array([0.2, 0.24, 0.24, 0.16, 0.16, 0.0])

    def table(traces):
        return [np.tile(shrink, (len(t) - 1, 1)) for t in traces]
    buf = io.StringIO()
    stats = write_laminate_gcode((along, table(along)), [(across, table(across), layers, "across")],
                                 PROFILE, buf)
    parsed = parse(buf.getvalue())
    layer_mm = np.clip(PROFILE.shrink_curve.theta(shrink)[0], PROFILE.thickness_mm.min,
                       PROFILE.thickness_mm.max)
    for layer in range(1, PROFILE.layers + 1):
        moves = [m for m in parsed.layer_moves(layer) if m.extruding]
        along_x = all(m.start[1] == pytest.approx(m.end[1]) for m in moves)
        assert along_x != (layer in layers), layer
        zs = np.array([m.end[2] for m in moves])
        assert np.ptp(zs) == 0 and zs[0] == pytest.approx(layer_mm[:layer].sum(), abs=1e-3)
    assert stats["traces"] == 3 and stats["across_traces"] == 4
    assert "upper_traces" not in stats
    area = PROFILE.filament_mm ** 2 * np.pi / 4
    mine = np.isin(np.arange(1, 7), layers)
    want = (3 * 20 * layer_mm[~mine].sum() + 4 * 20 * layer_mm[mine].sum()) \
        * PROFILE.path_width_mm / area
    assert stats["filament_mm"] == pytest.approx(want, rel=1e-3)
    # Each straight trace merges into one chord; each set counted once.
    assert stats["segments"] == 3 + 4
    assert "3 / 4 (along / across)" in buf.getvalue()


def test_a_terrain_plan_prints_two_layers_on_paths_across_its_own(tmp_path):
    """End to end: the plan keeps two layers across, gives them stripes across d,
    reports each set of paths, and its G-code starts those layers on them."""
    from hostd import planner
    hf = shapes.terrain_tile(width_mm=60.0, depth_mm=45.0, height_mm=12.5)
    np.save(tmp_path / "t.npy", hf.z)
    (tmp_path / "t.yaml").write_text("pixel_mm: %r\nmethod: free\n" % hf.pixel_mm)
    plan = planner.run(tmp_path / "t.npy", PROFILE, tmp_path / "out")
    r = plan.report
    assert r["curvature"]["across"]["kept"] and plan.across_toolpaths is not None
    # The constant the layers across were programmed with, and whether it was measured.
    assert (r["curvature"]["across"]["c_across"], r["curvature"]["across"]["across_status"]) \
        == (PROFILE.curvature.bilayer_c, "uncalibrated")
    across = r["toolpath"]["across"]
    # Stripes follow a field only as far as it is a gradient's turned by a quarter: the
    # across paths meet d's divergence where the plan's meet its curl (10 degrees here).
    assert across["coverage"] > 0.9 and across["direction_angle_deg"]["p95"] < 15.0
    assert 0.8 * 0.48 < across["spacing_mm"]["p05"] and across["spacing_mm"]["p95"] < 1.2 * 0.48
    assert r["gcode"]["across_traces"] == len(plan.across_toolpaths.traces)
    assert r["gcode"]["traces"] == len(plan.toolpaths.traces)
    parsed = parse((tmp_path / "out" / "t.gcode").read_text())
    paths = {"lower": plan.toolpaths, "upper": plan.upper_toolpaths,
             "across": plan.across_toolpaths}
    groups = plan.curvature.laminate.groups()
    assert sorted(k for ks in groups.values() for k in ks) == list(range(1, PROFILE.layers + 1))
    for role, layers in groups.items():
        for layer in layers:
            first = next(m.start[:2] for m in parsed.layer_moves(layer) if m.extruding)
            assert np.allclose(first, paths[role].traces[0][0], atol=0.01), (role, layer)


def test_three_sets_of_paths_each_print_their_own_layers():
    """Halves along d turned apart and two layers across: each layer prints its own
    set's paths, and the file counts each set."""
    from pipeline.gcode.writer import write_laminate_gcode
    xs = np.linspace(0, 20, 21)
    sets = {"lower": [np.c_[xs, np.full(21, y)] for y in (0.0, 10.0)],
            "upper": [np.c_[xs, np.full(21, y)] for y in (2.0, 12.0, 22.0)],
            "across": [np.c_[np.full(21, x), xs] for x in (0.0, 10.0, 20.0, 5.0)]}
    layers = {"lower": [1, 3], "upper": [4, 6], "across": [2, 5]}
    shrink = np.array([0.24, 0.05, 0.24, 0.16, 0.0, 0.16])

    def table(traces):
        return [np.tile(shrink, (len(t) - 1, 1)) for t in traces]
    buf = io.StringIO()
    stats = write_laminate_gcode(
        (sets["lower"], table(sets["lower"])),
        [(sets[r], table(sets[r]), layers[r], r) for r in ("across", "upper")], PROFILE, buf,
        center=False)
    parsed = parse(buf.getvalue())
    for role, ks in layers.items():
        for k in ks:
            first = next(m.start[:2] for m in parsed.layer_moves(k) if m.extruding)
            assert np.allclose(first, sets[role][0][0], atol=1e-3), (role, k)
    assert (stats["traces"], stats["upper_traces"], stats["across_traces"]) == (2, 3, 4)
    assert "2 / 4 / 3 (lower half along / across / upper half along)" in buf.getvalue()


def _settled(mean_mm):
    """A settled sheet whose mean displacement is ``mean_mm``."""
    from pipeline.simulation.forward import SimResult
    return SimResult(vertices=np.zeros((3, 3)), displacement_mm=np.full(3, mean_mm),
                     mean_displacement_mm=mean_mm, max_displacement_mm=mean_mm, iterations=10,
                     converged=True, mirrored=False, clamped_edges=0, sheet_vertices=3,
                     coarse_iterations=0, energy_history=[1.0], timing_s={"total": 0.1})


@pytest.mark.parametrize("probe_mm, rest_mm, kept", [(0.85, None, False), (0.7, 0.85, False),
                                                     (0.7, 0.75, True)])
def test_layers_across_are_kept_only_where_the_sheet_rests_a_fifth_closer(probe_mm, rest_mm, kept):
    """A third set of stripes costs tool-path time and traces: the layers across are kept
    only at 20 % closer (the twist at 5 %), settled on only when the probe is already."""
    from pipeline.simulation.programmed import ACROSS_GAIN, _tried
    assert ACROSS_GAIN == 0.2
    settles = []

    def settle(start=None, iterations=None):
        settles.append(iterations)
        return _settled(probe_mm if iterations else rest_mm)
    (program, sim), tried = _tried("bilayer", _settled(1.0), [("stack", settle, ACROSS_GAIN)])
    assert tried["kept"] == kept and program == ("stack" if kept else "bilayer")
    assert tried["tried_at_rest"] == (rest_mm is not None) == (len(settles) == 2)


@pytest.mark.parametrize("layers", [4, 5, 7])
def test_any_layer_count_of_four_or_more_keeps_the_metric_and_programs_the_curvature(layers):
    """Four, five or seven layers: two across (the second and second-last), the others
    along d keep the layout's shrink as their mean (a middle layer at the mean) and the
    stack bends as the target where the range allows."""
    d = np.tile([1.0, 0.0], (3, 1))
    K = np.array([np.diag([0.004, 0.006]), np.diag([-0.003, 0.002]), np.diag([0.0, -0.005])])
    sigma = np.array([0.12, 0.1, 0.08])
    lim = PROFILE.shrink_limits

    def layer_mm(s):
        return np.clip(PROFILE.shrink_curve.theta(np.asarray(s, float))[0],
                       PROFILE.thickness_mm.min, PROFILE.thickness_mm.max)
    lam = across_laminate(K, d, sigma, layer_mm, layers, lim.s_min, lim.s_max, c=1.5)
    assert list(np.flatnonzero(lam.across) + 1) == [2, layers - 1]
    assert np.allclose(lam.metric(d)[:, 0, 0], sigma)
    assert np.allclose(lam.curvature(d, c=1.5), K, atol=2e-4)
