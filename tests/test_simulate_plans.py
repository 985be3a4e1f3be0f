"""A whole plan of the paper's method (generic profile, coarse sheet first) rises into
its target."""

import pytest

from pipeline.layout.isoline import flatten
from pipeline.simulation.forward import simulate

from meshes import longest_diameter


def _planned(name):
    """``name`` meshed, flattened and simulated as ``hostd plan`` does (generic
    profile: pits filled, smoothed by smooth_mm, l_u 0.25 mm, coarse sheet
    first), sigma clamped to the material's range. Returns (sim, diameter)."""
    from pipeline.input import shapes
    from pipeline.meshing.isoline import build_mesh
    from pipeline.profiles.profile import load_profile
    from pipeline.input.simplify import simplify
    from pipeline.input.validate import validate
    prof = load_profile("generic-0.5mm")
    mp, lim = prof.mesh, prof.shrink_limits
    hf, _ = validate(shapes.REFERENCE[name](), 2.0, bed_mm=prof.bed_mm)
    hf, _ = simplify(hf, mp.min_prominence_mm, mp.smooth_mm)
    mesh = build_mesh(hf, isoline_step_mm=mp.isoline_step_mm, l_sim_mm=mp.l_sim_mm,
                      gradient_spacing_mm=mp.gradient_spacing_mm, l_u_mm=mp.l_u_mm)
    flat = flatten(mesh, s_min=lim.s_min, s_max=lim.s_max)
    return simulate(mesh, flat, s_min=lim.s_min, s_max=lim.s_max), longest_diameter(mesh)


@pytest.mark.slow
def test_planned_saddle_rises_within_one_percent():
    """Measured 0.86 % of its diameter (not at rest after 300 + 300
    iterations); with the degenerate hinges' bending rows kept, 5.7 %."""
    sim, d = _planned("saddle")
    assert sim.mean_displacement_mm < 0.01 * d, (sim.mean_displacement_mm / d, sim.iterations)
