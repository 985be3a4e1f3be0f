"""The free layout's sheet as printed: shrunk along each triangle's print direction, its
layers' thicknesses from the shrink, curvature programmed through them, settled by the
thin shell from (almost) flat, as it starts in the bath."""

import numpy as np

from pipeline.layout import curvature
from pipeline.simulation.shell import simulate_shell, tensor_rest, thickness_for

# The programmed sheet's start: a small bump the way the program rises (from exactly
# flat a sheet can creep, wrinkled, for hundreds of iterations before it pops).
BATH_BUMP = 0.02


def simulate_free(hf, mesh, flat, profile):
    """Simulate the sheet the free layout ``flat`` of ``mesh`` (the target, from ``hf``)
    prints with ``profile``. Returns (:class:`pipeline.layout.curvature.CurvatureProgram`,
    the simulation result)."""
    lim = profile.shrink_limits
    # The printed sheet shrinks only within the material's range (the G-code clamps the
    # thickness the same way), so the simulation shrinks by the clamped sigma.
    sigma = np.clip(flat.sigma, lim.s_min, lim.s_max)
    thick = thickness_for(sigma, profile.shrink_curve, profile.layers,
                          profile.thickness_mm.min, profile.thickness_mm.max)
    # Curvature through the layers: the lower layers shrink more where the target
    # rises, so bending pulls toward the target instead of toward flat; the two layer
    # groups turn apart where it twists.
    program = curvature.program(
        curvature.target_tensor(hf, mesh, flat, sigma), mesh.faces, flat.xy, flat.direction,
        sigma, thick, lim.s_min, lim.s_max, c=profile.curvature.bilayer_c,
        turn_max_deg=profile.curvature.turn_max_deg)
    A, B = program.group_tensors(flat.direction, sigma)
    sim = simulate_shell(mesh.vertices, mesh.faces, flat.xy, tensor_rest(flat.xy, mesh.faces,
                                                                         (A + B) / 2),
                         thick, theta_rest=program.theta_rest, pop=BATH_BUMP)
    return program, sim
