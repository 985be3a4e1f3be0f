"""Forward simulation (pipeline.simulate, paper 6.2.4): does the layout rise into the target?"""

import numpy as np
import pytest

from pipeline.flatten import flatten
from pipeline.simulate import SimResult, align, simulate

from meshes import (isoline_mesh, longest_diameter, reference_mesh, spherical_cap,
                    starfish_like, two_peaks)

RNG = np.random.default_rng(7)


def returns_to_target(mesh, rel_tol=0.01, **simulate_kwargs):
    """Flatten ``mesh``, simulate the layout, and check the mean displacement
    from the target is below ``rel_tol`` of the longest diameter.

    Reusable on any Mesh (test meshes here, the mesher's output elsewhere).
    Returns (FlatResult, SimResult, relative mean displacement).
    """
    flat = flatten(mesh)
    sim = simulate(mesh, flat, **simulate_kwargs)
    rel = sim.mean_displacement_mm / longest_diameter(mesh)
    assert rel < rel_tol, (rel, sim.max_displacement_mm, sim.iterations, sim.converged)
    return flat, sim, rel


def test_dome_returns_to_target():
    flat, sim, rel = returns_to_target(reference_mesh("dome"), rel_tol=0.01)
    assert isinstance(sim, SimResult) and sim.converged
    assert sim.vertices.shape == flat.xy.shape[:1] + (3,)
    assert sim.max_displacement_mm >= sim.mean_displacement_mm > 0
    assert not sim.mirrored
    report = sim.report()
    assert set(report) >= {"mean_displacement_mm", "max_displacement_mm"}


def test_exact_cap_layout_rises_into_the_cap():
    """The analytic layout of a spherical cap (ring at arc length s on a circle
    of radius s) rises back into the cap: the simulation on its own, without
    the flattening's compromises."""
    mesh, s = spherical_cap(84.5, 25.0, ring_arc_mm=4.0, l_u=1.5)
    V = mesh.vertices
    r3 = np.hypot(V[:, 0], V[:, 1])
    arc = 84.5 * np.arcsin(np.clip(r3 / 84.5, 0, 1))  # meridian arc length from the apex
    xy = V[:, :2] * np.where(r3 > 0, arc / np.maximum(r3, 1e-12), 1.0)[:, None]
    sim = simulate(mesh, xy)
    assert sim.converged
    assert sim.mean_displacement_mm < 0.005 * longest_diameter(mesh)
    # a layout that is the target's own projection (sigma 0 wherever the
    # projection shortens nothing) cannot rise as far
    flat_proj = simulate(mesh, V[:, :2])
    assert flat_proj.mean_displacement_mm > 5 * sim.mean_displacement_mm


def test_sheet_that_pops_down_is_mirrored():
    """Started with a downward bump the dome settles upside down; its mirror
    image (what the upward start reaches) is kept and reported."""
    mesh = reference_mesh("dome")
    flat = flatten(mesh)
    up = simulate(mesh, flat)
    down = simulate(mesh, flat, pop=-0.15)
    assert down.mirrored and not up.mirrored
    # every constraint is reflection-invariant: the same shape, mirrored
    assert down.mean_displacement_mm == pytest.approx(up.mean_displacement_mm, rel=1e-6)


def test_clamping_sigma_to_printable_range_is_counted_and_costs_accuracy():
    mesh = reference_mesh("dome")
    flat = flatten(mesh)
    free = simulate(mesh, flat)
    clamped = simulate(mesh, flat, s_min=0.0, s_max=0.02)
    assert free.clamped_edges == 0
    assert clamped.clamped_edges == int(np.count_nonzero((flat.sigma < 0) | (flat.sigma > 0.02)))
    assert clamped.mean_displacement_mm > 3 * free.mean_displacement_mm


def test_align_undoes_a_rigid_motion():
    T = RNG.normal(size=(200, 3)) * [40, 30, 10]
    q, _ = np.linalg.qr(RNG.normal(size=(3, 3)))
    R = q * np.sign(np.linalg.det(q))  # a rotation
    P = T @ R.T + [5.0, -3.0, 12.0]
    aligned, d = align(P, T)
    assert d.max() < 1e-9
    np.testing.assert_allclose(aligned, T, atol=1e-9)
    # a reflection is not a rigid motion: it cannot be undone
    _, d = align(T * [1, 1, -1], T)
    assert d.mean() > 1.0


# Shapes with lobes and long flanks: the bending toward flat (w_bending 0.025,
# like a sheet ~0.6-0.8 mm thick at these edge lengths) partly unrolls their
# nearly developable rims and lobes. At equilibrium (run to convergence: cut
# short, the sheet is still closer to the target, 0.6-0.7 %) measured 1.1 %
# of the diameter for the two-peak shape and 1.5 % for the starfish-like one
# (the paper's printed parts: 1.4-2.2 %).
LOBED = {
    "two_peaks": lambda: isoline_mesh(two_peaks(), spacing_mm=2.0, l_u=2.0),
    "starfish_like": lambda: isoline_mesh(starfish_like(neck=0.7, height_mm=18.0),
                                          spacing_mm=2.0, l_u=2.0),
}


EQUILIBRIUM = {"iterations": 1000, "tol": 1e-5}


@pytest.mark.parametrize("name", sorted(LOBED))
def test_lobed_shapes_return_close_to_target(name):
    _, sim, _ = returns_to_target(LOBED[name](), rel_tol=0.03, **EQUILIBRIUM)
    assert sim.converged


@pytest.mark.xfail(reason="lobes unroll under bending toward flat: 1.1-1.5 % of the "
                          "diameter at equilibrium, see LOBED", strict=True)
@pytest.mark.parametrize("name", sorted(LOBED))
def test_lobed_shapes_return_within_one_percent(name):
    returns_to_target(LOBED[name](), rel_tol=0.01, **EQUILIBRIUM)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["saddle", "starfish"])
def test_planned_layouts_rise_within_one_percent(name):
    """The saddle and the starfish as ``hostd plan`` meshes them (generic
    profile: pits filled, smoothed by smooth_mm, l_u 0.25 mm), flattened with
    the paper's weights and simulated with sigma clamped to the material's
    range, rise to within 1 % of their diameter. Measured 0.90 % and 0.85 %;
    with the degenerate hinges' bending rows kept, 5.7 % and 2.1 %.
    The starfish's figure depends on the simulation's start as much as on
    its layout (its arms bend without stretching; see ``simulate``'s ``pop``):
    0.85 % is what the default start reaches on the full mesh."""
    from pipeline import shapes
    from pipeline.mesh import build_mesh
    from pipeline.profile import load_profile
    from pipeline.simplify import simplify
    from pipeline.validate import validate
    prof = load_profile("generic-0.5mm")
    mp, lim = prof.mesh, prof.shrink_limits
    hf, _ = validate(shapes.REFERENCE[name](), 2.0, bed_mm=prof.bed_mm)
    hf, _ = simplify(hf, mp.min_prominence_mm, mp.smooth_mm)
    mesh = build_mesh(hf, isoline_step_mm=mp.isoline_step_mm,
                      gradient_spacing_mm=mp.gradient_spacing_mm, l_u_mm=mp.l_u_mm)
    flat = flatten(mesh, s_min=lim.s_min, s_max=lim.s_max)
    sim = simulate(mesh, flat, s_min=lim.s_min, s_max=lim.s_max)
    assert sim.mean_displacement_mm < 0.01 * longest_diameter(mesh), (
        sim.mean_displacement_mm, sim.iterations, sim.converged)


@pytest.mark.parametrize("name,size", [
    ("dome", {"diameter_mm": 80.0, "height_mm": 18.0}),
    ("saddle", {"length_mm": 80.0, "width_mm": 60.0, "height_mm": 16.0})])
def test_coarse_sheet_rises_like_the_full_mesh(name, size):
    """The coarse sheet (isoline arcs cut to 2 mm, diagonals shrunk along the
    isolines only) ends within 0.5 % of the diameter of where the full mesh
    ends. Measured: dome 0.21 % against 0.34 %, saddle 1.43 % against 1.02 %;
    with the coarse diagonals kept at their flat length the saddle is 2.14 %."""
    from pipeline import shapes
    from pipeline.mesh import build_mesh
    mesh = build_mesh(shapes.REFERENCE[name](**size), l_sim_mm=2.0)
    flat = flatten(mesh, s_min=0.0, s_max=0.343)
    full = simulate(mesh, flat, s_min=0.0, s_max=0.343, coarse=False)
    coarse = simulate(mesh, flat, s_min=0.0, s_max=0.343)
    assert coarse.sheet_vertices < len(mesh.vertices) / 4 and full.sheet_vertices == len(mesh.vertices)
    assert coarse.vertices.shape == mesh.vertices.shape
    d = longest_diameter(mesh)
    assert abs(coarse.mean_displacement_mm - full.mean_displacement_mm) < 0.005 * d, (
        coarse.mean_displacement_mm / d, full.mean_displacement_mm / d)
