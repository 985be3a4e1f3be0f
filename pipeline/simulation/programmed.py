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
# The twist is added to the sheet the bilayer has settled (which way each region rises
# is the bilayer's answer) and tried for this many iterations before the sheet settles
# on with it: after 80 the sheet is as much closer or further as at rest on every
# benchmark model (after 40 not yet on the starfish or the long saddle), and a real
# tile, which keeps no crossing, pays 1.5 s instead of a second settle (8-9 s).
PROBE_ITERATIONS = 80


def simulate_free(hf, mesh, flat, profile, twist=True):
    """Simulate the sheet the free layout ``flat`` of ``mesh`` (the target, from ``hf``)
    prints with ``profile``: settled from (almost) flat with the bilayer program, then,
    with ``twist`` (and the profile's ``curvature.turn_max_deg``), with the layer groups
    turned apart by the twist, kept where it rests :data:`TWIST_GAIN` closer. Returns
    (:class:`pipeline.layout.curvature.CurvatureProgram`, with ``twist`` the comparison
    or None, the simulation result)."""
    lim = profile.shrink_limits
    # The printed sheet shrinks only within the material's range (the G-code clamps the
    # thickness the same way), so the simulation shrinks by the clamped sigma.
    laid = np.clip(flat.sigma, lim.s_min, lim.s_max)
    cp = profile.curvature

    def thickness(s):
        return thickness_for(s, profile.shrink_curve, profile.layers,
                             profile.thickness_mm.min, profile.thickness_mm.max)
    K = curvature.target_tensor(hf, mesh, flat, laid)
    # Where the layout leaves no shrink to bend with, a little is added along d.
    sigma = curvature.room_for(K, flat.direction, laid, thickness(laid), lim.s_min,
                               lim.s_max, c=cp.bilayer_c, added_max=cp.max_added_shrink)
    thick = thickness(sigma)

    added = _added(flat.xy, mesh.faces, laid, sigma)

    def programmed(turn_max_deg):
        # Curvature through the layers: the lower layers shrink more where the target
        # rises, so bending pulls toward the target instead of toward flat; the two
        # layer groups turn apart where it twists.
        prog = curvature.program(K, mesh.faces, flat.xy, flat.direction, sigma, thick,
                                 lim.s_min, lim.s_max, c=cp.bilayer_c,
                                 turn_max_deg=turn_max_deg)
        prog.added = added
        return prog

    def settle(prog, **kw):
        A, B = prog.group_tensors(flat.direction, sigma)
        return simulate_shell(mesh.vertices, mesh.faces, flat.xy,
                              tensor_rest(flat.xy, mesh.faces, (A + B) / 2), thick,
                              theta_rest=prog.theta_rest, pop=BATH_BUMP, **kw)

    program = programmed(0.0)
    sim = settle(program)
    # Crossed groups need an even layer count: a middle layer printed with either group
    # would shear the sheet's mean shrink by twist / (2 * layers).
    turn = cp.turn_max_deg if profile.layers % 2 == 0 else 0.0
    if not twist or turn <= 0:
        return program, sim
    crossed = programmed(turn)
    probe = settle(crossed, start=sim.vertices, iterations=PROBE_ITERATIONS)
    tried = probe
    if probe.mean_displacement_mm < (1.0 - TWIST_GAIN) * sim.mean_displacement_mm:
        tried = _continued(settle(crossed, start=probe.vertices), sim, probe)
    kept = tried.mean_displacement_mm < (1.0 - TWIST_GAIN) * sim.mean_displacement_mm
    choice = (crossed, tried) if kept else (program, sim)
    choice[0].twist = {"kept": bool(kept), "turn_max_deg": float(turn),
                       "crossed_mean_displacement_mm": float(tried.mean_displacement_mm),
                       "crossed_at_rest": tried is not probe,
                       "along_mean_displacement_mm": float(sim.mean_displacement_mm),
                       "crossing_deg": crossed.crossing_deg()}
    return choice


def _continued(final, *before):
    """``final``, a settle that went on from the shapes of ``before``, with their
    iterations and energies counted in: SimResult."""
    import dataclasses
    total = sum(b.timing_s["total"] for b in before) + final.timing_s["total"]
    return dataclasses.replace(
        final, iterations=sum(b.iterations for b in before) + final.iterations,
        energy_history=[e for b in before for e in b.energy_history] + final.energy_history,
        timing_s={"full": total, "total": total})


def _added(xy, faces, laid, sigma):
    """The shrink the program added to the layout's ``laid``: {area_fraction, max}."""
    P = np.asarray(xy, dtype=float)[faces]
    u, v = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    area = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    return {"area_fraction": float(area[sigma > laid].sum() / max(area.sum(), 1e-12)),
            "max": float((sigma - laid).max(initial=0.0))}
