"""The free sheet checked once, coarse to fine: the trials on a coarse sheet, only the
program chosen settled on the plan's mesh, from the coarse sheet's rest."""

import numpy as np
import pytest

from pipeline.geometry import HeightField
from pipeline.meshing.grid import build_grid_mesh
from pipeline.simulation import programmed, staged
from test_curvature_program import plan_layout
from test_laminate import small_terrain


def _saddle():
    from pipeline.input import shapes
    hf = shapes.hyperbolic_paraboloid(diameter_mm=60.0, height_mm=15.0)
    return (hf,) + plan_layout(hf)


@pytest.fixture(scope="module")
def saddle():
    return _saddle()


def _recorded(monkeypatch):
    """Every settle of :mod:`programmed`: (vertex count, its ``start`` or None)."""
    calls = []
    shell = programmed.simulate_shell

    def recorded(vertices, *args, **kw):
        calls.append((len(vertices), kw.get("start")))
        return shell(vertices, *args, **kw)
    monkeypatch.setattr(programmed, "simulate_shell", recorded)
    return calls


def test_the_trials_run_on_the_coarse_sheet_and_the_plans_mesh_settles_once(saddle,
                                                                              monkeypatch):
    """The bilayer, the probes and the continued settle run on the 2.5 mm sheet; the
    1 mm mesh is settled once, from the coarse sheet's rest carried onto it."""
    hf, profile, mesh, flat = saddle
    cmesh, _ = staged.coarse_sheet(hf, mesh, flat)
    calls = _recorded(monkeypatch)
    prog, sim = staged.simulate_free(hf, mesh, flat, profile)
    sizes = [n for n, _ in calls]
    assert sizes[:-1] == [len(cmesh.vertices)] * (len(calls) - 1) and len(calls) >= 4
    assert sizes[-1] == len(mesh.vertices) > 4 * len(cmesh.vertices)
    start = calls[-1][1]
    assert start is not None
    # Carried, not flat: the start already rises into the saddle.
    assert np.ptp(start[:, 2]) > 0.5 * np.ptp(np.asarray(mesh.vertices)[:, 2])
    assert sim.coarse_iterations > sim.iterations > 0
    # The report counts the coarse sheet's trials and the plan's mesh's settle apart.
    counts = sim.report()
    assert (counts["coarse_iterations"], counts["full_iterations"]) == (
        sim.coarse_iterations, sim.iterations)
    assert {"coarse", "full", "total", "coarse_cpu", "full_cpu"} <= set(sim.timing_s)
    # The program chosen on the coarse sheet is made on the plan's mesh.
    assert prog.across["kept"] and len(prog.theta_rest) > len(cmesh.faces)
    assert prog.layout is not None and len(prog.layout.xy) == len(mesh.vertices)


@pytest.mark.parametrize("shape", ["saddle", "terrain"])
def test_the_fast_settle_rests_where_the_full_settle_of_the_same_program_does(shape,
                                                                               saddle):
    """Within 10 % (or 0.05 mm) of the same program settled on the plan's mesh from the
    bath, the bilayer first, as the trials settle the one they keep."""
    hf, profile, mesh, flat = saddle if shape == "saddle" else small_terrain()
    prog, fast = staged.simulate_free(hf, mesh, flat, profile)
    ref_prog, ref = staged.simulate_free(hf, mesh, flat, profile, reference=True)
    assert programmed.choice_of(prog) == programmed.choice_of(ref_prog)
    assert ref.iterations > 3 * fast.iterations
    gap = abs(fast.mean_displacement_mm - ref.mean_displacement_mm)
    assert gap < max(0.1 * ref.mean_displacement_mm, 0.05), (fast.mean_displacement_mm,
                                                             ref.mean_displacement_mm)


def test_a_mesh_not_much_finer_than_the_coarse_sheet_is_tried_on_itself(monkeypatch):
    """Every settle on the plan's own 2 mm mesh: no coarse sheet to carry from."""
    hf, profile, _, _ = small_terrain()
    from pipeline.layout.free import flatten_free
    mesh = build_grid_mesh(hf, 2.0)
    lim = profile.shrink_limits
    flat = flatten_free(mesh, lim.s_min, lim.s_max, iterations=100)
    calls = _recorded(monkeypatch)
    staged.simulate_free(hf, mesh, flat, profile)
    assert {n for n, _ in calls} == {len(mesh.vertices)}


def test_a_large_sheet_tries_on_coarser_triangles_than_a_small_one():
    """The trials' triangles are 2.5 mm on a 60 mm model and 3 mm from about 150 mm of
    diagonal on (where 3 mm rests as 2.5 mm does), and never coarser."""
    def square(side_mm):
        n = int(side_mm / 0.5) + 1
        return build_grid_mesh(HeightField(np.zeros((n, n)), 0.5), 5.0)
    assert staged.coarse_spacing_mm(square(42.0)) == staged.COARSE_MM == 2.5
    assert staged.coarse_spacing_mm(square(125.0)) == pytest.approx(3.0, abs=0.05)
    assert staged.coarse_spacing_mm(square(400.0)) == staged.COARSE_MAX_MM == 3.0


def test_the_coarse_sheet_carries_the_layout_map():
    """A layout that is a rotation of the target's footprint carries to the coarse
    vertices as that rotation; each coarse triangle takes the fine one's direction."""
    n = 81
    hf = HeightField(np.zeros((n, n)), 0.5, source="flat")
    mesh = build_grid_mesh(hf, 1.0)
    V = np.asarray(mesh.vertices)
    a = np.radians(30.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    from pipeline.layout.free import FreeLayout
    m = len(mesh.faces)
    d = np.tile([np.cos(a), np.sin(a)], (m, 1))
    flat = FreeLayout(xy=V[:, :2] @ R.T, direction=d, sigma=np.full(m, 0.1), iterations=0,
                      residual=0.0, flipped=0, invalid_area_fraction=0.0,
                      stretch_area_fraction=0.0, overshrink_area_fraction=0.0)
    cmesh, cflat = staged.coarse_sheet(hf, mesh, flat, 2.5)
    CV = np.asarray(cmesh.vertices)
    assert len(CV) < len(V) / 4
    assert np.allclose(cflat.xy, CV[:, :2] @ R.T, atol=1e-9)
    assert np.allclose(cflat.direction, d[:len(cmesh.faces)]) and np.allclose(cflat.sigma, 0.1)


def test_a_shape_carried_to_the_fine_mesh_keeps_what_is_linear():
    """A plane over the coarse sheet is the same plane at the fine vertices, beyond the
    coarse sheet's edge too."""
    n = 81
    hf = HeightField(np.zeros((n, n)), 0.5, source="flat")
    fine, coarse = build_grid_mesh(hf, 1.0), build_grid_mesh(hf, 3.0)
    CV, V = np.asarray(coarse.vertices), np.asarray(fine.vertices)

    def plane(P):
        return np.c_[P[:, 0] + 2.0, -P[:, 1], 0.3 * P[:, 0] - 0.2 * P[:, 1] + 1.0]
    assert np.allclose(staged.carried(coarse, plane(CV), V), plane(V), atol=1e-9)

