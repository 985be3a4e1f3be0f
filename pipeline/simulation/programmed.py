"""The free layout's sheet as printed: shrunk along each triangle's print direction, its
layers' thicknesses from the shrink, curvature programmed through them, settled by the
thin shell from (almost) flat, as it starts in the bath."""

import numpy as np

from pipeline.layout import curvature
from pipeline.simulation.shell import simulate_shell, tensor_rest, thickness_for

# The programmed sheet's start: a small bump the way the program rises (from exactly
# flat a sheet can creep, wrinkled, for hundreds of iterations before it pops).
BATH_BUMP = 0.02
# Layer groups turned apart print a second set of stripes (about twice the tool-path
# time) and, on real terrain, can rest further off; they are kept only where the sheet
# then rests at least this much closer (measured: 20-33 % closer on the elongated peak,
# three islands, hyperbolic paraboloid and monkey saddle, 8-9 % on the starfish and the
# terrain tile; from 1 % closer to 13 % further on the real tiles, the dome and the long
# saddle).
TWIST_GAIN = 0.05


def simulate_free(hf, mesh, flat, profile, twist=True):
    """Simulate the sheet the free layout ``flat`` of ``mesh`` (the target, from ``hf``)
    prints with ``profile``. With ``twist`` (and the profile's ``curvature.turn_max_deg``)
    the sheet is also simulated with its layer groups turned apart and printed so where
    it rests :data:`TWIST_GAIN` closer. Returns (:class:`pipeline.layout.curvature.
    CurvatureProgram`, with ``twist`` the comparison or None, the simulation result)."""
    lim = profile.shrink_limits
    # The printed sheet shrinks only within the material's range (the G-code clamps the
    # thickness the same way), so the simulation shrinks by the clamped sigma.
    sigma = np.clip(flat.sigma, lim.s_min, lim.s_max)
    cp = profile.curvature

    def thickness(s):
        return thickness_for(s, profile.shrink_curve, profile.layers,
                             profile.thickness_mm.min, profile.thickness_mm.max)
    K = curvature.target_tensor(hf, mesh, flat, sigma)
    # Where the layout leaves no shrink to bend with, a little is added along d.
    laid = sigma
    sigma = curvature.room_for(K, flat.direction, laid, thickness(laid), lim.s_min,
                               lim.s_max, c=cp.bilayer_c, added_max=cp.max_added_shrink)
    thick = thickness(sigma)
    added = _added(flat.xy, mesh.faces, laid, sigma)

    def settle(turn_max_deg):
        # Curvature through the layers: the lower layers shrink more where the target
        # rises, so bending pulls toward the target instead of toward flat; the two
        # layer groups turn apart where it twists.
        prog = curvature.program(K, mesh.faces, flat.xy, flat.direction, sigma, thick,
                                 lim.s_min, lim.s_max, c=cp.bilayer_c,
                                 turn_max_deg=turn_max_deg)
        A, B = prog.group_tensors(flat.direction, sigma)
        return prog, simulate_shell(mesh.vertices, mesh.faces, flat.xy,
                                    tensor_rest(flat.xy, mesh.faces, (A + B) / 2), thick,
                                    theta_rest=prog.theta_rest, pop=BATH_BUMP)

    program, sim = settle(0.0)
    program.added = added
    # Crossed groups need an even layer count: a middle layer printed with either group
    # would shear the sheet's mean shrink by twist / (2 * layers).
    turn = cp.turn_max_deg if profile.layers % 2 == 0 else 0.0
    if not twist or turn <= 0:
        return program, sim
    crossed, sim_crossed = settle(turn)
    kept = sim_crossed.mean_displacement_mm < (1.0 - TWIST_GAIN) * sim.mean_displacement_mm
    crossed.added = added
    choice = (crossed, sim_crossed) if kept else (program, sim)
    choice[0].twist = {"kept": bool(kept), "turn_max_deg": float(turn),
                       "crossed_mean_displacement_mm": float(sim_crossed.mean_displacement_mm),
                       "along_mean_displacement_mm": float(sim.mean_displacement_mm),
                       "crossing_deg": crossed.crossing_deg()}
    return choice


def _added(xy, faces, laid, sigma):
    """The shrink the program added to the layout's ``laid``: {area_fraction, max}."""
    P = np.asarray(xy, dtype=float)[faces]
    u, v = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    area = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    return {"area_fraction": float(area[sigma > laid].sum() / max(area.sum(), 1e-12)),
            "max": float((sigma - laid).max(initial=0.0))}
