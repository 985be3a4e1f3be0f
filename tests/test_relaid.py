"""The layout solved again for the shrink the stack prints: across the paths by the
layers across, along them at least the room the bilayer takes."""

import numpy as np
import pytest

from pipeline.geometry import HeightField, signed_areas_2d
from pipeline.layout import curvature
from pipeline.layout.compensate import relaid
from pipeline.meshing.grid import build_grid_mesh
from test_laminate import small_terrain


def _square(size_mm=40.0, px=0.5):
    n = int(size_mm / px) + 1
    return build_grid_mesh(HeightField(np.zeros((n, n)), px, source="flat"), 1.0)


def _turned(angle_deg, m):
    a = np.radians(angle_deg)
    return np.tile([np.cos(a), np.sin(a)], (m, 1))


def test_a_flat_sheet_is_laid_out_longer_by_what_the_layers_shrink():
    """A flat target printed with 5 % shrink across d (x) and 10 % along it: the layout
    is 1/0.95 as long across and 1/0.9 along, and d stays."""
    mesh = _square()
    m = len(mesh.faces)
    d = _turned(0.0, m)
    xy, d2, sigma, info = relaid(mesh.vertices, mesh.faces, mesh.vertices[:, :2], d,
                                 np.full(m, 0.05), np.full(m, 0.10), 0.0, 0.34)
    extent = np.ptp(xy, axis=0) / np.ptp(mesh.vertices[:, :2], axis=0)
    assert extent == pytest.approx([1 / 0.9, 1 / 0.95], rel=1e-3)
    assert sigma == pytest.approx(0.10, abs=1e-4)
    assert np.allclose(d2, d, atol=1e-6) and info["residual"] < 1e-4


def test_where_nothing_is_asked_the_layout_and_its_free_directions_stay():
    """No shrink across and no room: the layout does not move, and where it stretches
    alike both ways (round-off picks its singular vectors) the direction the program
    chose stays."""
    mesh = _square()
    m = len(mesh.faces)
    d = _turned(30.0, m)
    xy, d2, sigma, info = relaid(mesh.vertices, mesh.faces, mesh.vertices[:, :2], d,
                                 np.zeros(m), np.zeros(m), 0.0, 0.34)
    assert info["max_move_mm"] < 1e-6
    assert np.allclose(d2, d, atol=1e-9) and np.allclose(sigma, 0.0, atol=1e-9)


def test_a_saddle_stack_is_printed_on_its_own_layout_and_rests_closer():
    """A 60 mm saddle's stack with two layers across, probed on the layout solved again
    for its shrink and on the first: relaid it is two thirds closer (on the first the
    shrink across puts the sheet off the target's metric), and the plan prints that
    layout, unfolded."""
    from pipeline.input import shapes
    from pipeline.simulation.programmed import simulate_free
    from test_curvature_program import plan_layout
    hf = shapes.hyperbolic_paraboloid(diameter_mm=60.0, height_mm=15.0)
    profile, mesh, flat = plan_layout(hf)
    prog, sim = simulate_free(hf, mesh, flat, profile)
    across = prog.across
    relaid_probe, first_probe = across["probe_mean_displacement_mm"]
    assert across["kept"] and across["chosen"] == 0 and across["relaid"]["chosen"]
    assert relaid_probe < 0.5 * first_probe
    assert across["relaid"]["flipped"] == 0 and across["relaid"]["residual"] < 0.01
    assert prog.layout is not flat and not np.allclose(prog.layout.xy, flat.xy)
    assert np.all(signed_areas_2d(prog.layout.xy, mesh.faces) > 0)


def test_the_twist_and_the_stacks_are_probed_side_by_side_and_one_settles_on(monkeypatch):
    """From the bilayer's rest the twist and both stacks across are probed; only the one
    chosen settles on to rest (the twist is not settled first and then dropped)."""
    from pipeline.input import shapes
    from pipeline.simulation import programmed
    from test_curvature_program import plan_layout
    hf = shapes.hyperbolic_paraboloid(diameter_mm=60.0, height_mm=15.0)
    profile, mesh, flat = plan_layout(hf)
    calls = []
    shell = programmed.simulate_shell

    def counted(*args, **kw):
        calls.append(kw.get("iterations"))
        return shell(*args, **kw)
    monkeypatch.setattr(programmed, "simulate_shell", counted)
    prog, sim = programmed.simulate_free(hf, mesh, flat, profile)
    probe = programmed.PROBE_ITERATIONS
    assert calls == [None, probe, probe, probe, None]
    assert prog.across["kept"] and not prog.twist["crossed_at_rest"]
    assert len(prog.across["probe_mean_displacement_mm"]) == 2
    assert sim.iterations > probe


def test_a_terrain_stack_stays_on_the_first_layout_where_that_probes_closer():
    """The small terrain tile rests closer on the first layout: that stack is kept, and
    the plan prints the first layout."""
    from pipeline.simulation.programmed import simulate_free
    hf, profile, mesh, flat = small_terrain()
    prog, sim = simulate_free(hf, mesh, flat, profile)
    across = prog.across
    relaid_probe, first_probe = across["probe_mean_displacement_mm"]
    assert across["kept"] and first_probe < relaid_probe
    assert across["chosen"] == 1 and not across["relaid"]["chosen"]
    assert prog.layout is flat


@pytest.mark.parametrize("folds_on", [1, 2])
def test_a_relaid_layout_that_would_fold_leaves_the_stack_on_the_layout_before(folds_on):
    """A solve whose layout folds is not printed: on the first pass the stack stays on the
    first layout, on the second on the first pass's, its program made there."""
    import pipeline.layout.compensate as compensate
    from pipeline.input import shapes
    from pipeline.simulation import programmed
    from test_curvature_program import plan_layout
    hf = shapes.hyperbolic_paraboloid(diameter_mm=60.0, height_mm=15.0)
    profile, mesh, flat = plan_layout(hf)
    original, layouts = compensate.relaid, []

    def folding(*args, **kw):
        xy, d, sigma, info = original(*args, **kw)
        if len(layouts) + 1 == folds_on:
            xy = xy * np.array([-1.0, 1.0])            # mirrored: every triangle turned over
        layouts.append(xy)
        return xy, d, sigma, info
    compensate.relaid = folding
    try:
        stack, _ = programmed._across_stack(
            curvature.surface_derivatives(hf, curvature.PROGRAM_SMOOTH_MM), mesh, flat,
            *_program_inputs(hf, mesh, flat, profile))
    finally:
        compensate.relaid = original
    assert stack.across["relaid"]["flipped"] > 0
    if folds_on == 1:
        assert stack.layout is flat
    else:
        assert np.allclose(stack.layout.xy, layouts[0])
    assert np.all(signed_areas_2d(stack.layout.xy, mesh.faces) > 0)


def _program_inputs(hf, mesh, flat, profile):
    """K, sigma, profile, thickness, turn and the bilayer program, as simulate_free makes
    them for the stack."""
    from pipeline.simulation import programmed
    from pipeline.simulation.shell import thickness_for
    lim, cp = profile.shrink_limits, profile.curvature

    def thickness(s):
        return thickness_for(s, profile.shrink_curve, profile.layers,
                             profile.thickness_mm.min, profile.thickness_mm.max)
    laid = np.clip(flat.sigma, lim.s_min, lim.s_max)
    K = curvature.target_tensor(hf, mesh, flat, laid)
    sigma = curvature.room_for(K, flat.direction, laid, thickness(laid), lim.s_min, lim.s_max,
                               c=cp.bilayer_c, added_max=cp.max_added_shrink)
    bilayer = programmed._program_on(mesh, flat, profile, thickness, K, sigma)
    return K, sigma, profile, thickness, cp.turn_max_deg, bilayer


def test_the_stretched_rotation_is_the_stretch_times_the_nearest_rotation():
    """Written out per component, the projection gives what the matrices give: ``D R``
    with ``R`` the rotation nearest ``D^-1 J`` (its polar factor)."""
    from scipy.linalg import polar
    from pipeline.layout.compensate import _stretched_rotation
    rng = np.random.default_rng(3)
    J = np.eye(2) + 0.3 * rng.standard_normal((50, 2, 2))
    ang = rng.uniform(0, np.pi, 50)
    d = np.c_[np.cos(ang), np.sin(ang)]
    lam, a = rng.uniform(1.0, 1.4, 50), rng.uniform(1.0, 1.1, 50)
    e = np.c_[-d[:, 1], d[:, 0]]
    D = (lam[:, None, None] * np.einsum("mi,mj->mij", d, d)
         + a[:, None, None] * np.einsum("mi,mj->mij", e, e))
    want = []
    for Dk, Jk in zip(D, J):
        R, _ = polar(np.linalg.solve(Dk, Jk))
        want.append(Dk @ R if np.linalg.det(R) > 0 else np.full((2, 2), np.nan))
    want = np.array(want)
    ok = np.isfinite(want[:, 0, 0])
    assert ok.sum() > 40
    assert np.allclose(_stretched_rotation(J, d, lam, a)[ok], want[ok], atol=1e-12)
