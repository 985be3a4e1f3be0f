"""The free layout's sheet as printed: shrunk along each triangle's print direction, its
layers' thicknesses from the shrink, curvature programmed through them, settled by the
thin shell from (almost) flat, as it starts in the bath."""

import numpy as np

from pipeline.geometry import signed_areas_2d
from pipeline.layout import curvature
from pipeline.layout.laminate import across_laminate
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
# Layers across print a set of stripes of their own across the others: tool paths take
# half as long again, and a set across a dome's isolines, which fan out from its top,
# forks into hundreds of traces. They are kept only where the sheet then rests at least
# a fifth closer (measured: 43-81 % on the starfish, elongated peak, long saddle, terrain
# tile and three islands; 6-13 % on the dome, the monkey saddle and the coast tile).
ACROSS_GAIN = 0.2
# Layouts solved again for the stack's shrink, each for the stack made on the one before
# (the starfish: 0.106 % and its arm tips 2.1-2.3 mm after one, 0.100 % and 2.0-2.1 mm after
# two, the same after three).
RELAY_PASSES = 2


def simulate_free(hf, mesh, flat, profile, twist=True, across=True, tally=None, relief=None):
    """Simulate the sheet the free layout ``flat`` of ``mesh`` (the target, from ``hf``)
    prints with ``profile``: settled from (almost) flat with the bilayer program; from
    there, side by side (:func:`_tried`), with ``twist`` (and the profile's
    ``curvature.turn_max_deg``) the layer groups turned apart by the twist, kept where it
    rests :data:`TWIST_GAIN` closer, and with ``across`` (and ``curvature.across_layers``)
    two layers across the paths (:mod:`pipeline.layout.laminate`, its halves along them
    turned apart too), kept where it rests :data:`ACROSS_GAIN` closer. Returns
    (:class:`pipeline.layout.curvature.CurvatureProgram`, with ``twist`` and ``across``
    the comparisons or None, the simulation result). ``tally``: a list that gets the
    iterations of every settle; ``relief``: the HeightField the program reads the
    target's curvature from, where not ``hf`` (:func:`pipeline.layout.curvature.relief`)."""
    make = Programs(hf, mesh, flat, profile, tally, relief)
    programmed, settle, cp = make.programmed, make.settle, make.cp
    program = bilayer = programmed(0.0)
    sim = settle(program)
    turn = make.turn
    # Each way on is probed from the bilayer's rest, side by side, and only the one
    # chosen settles on: the twist tried first and settled on its own, then dropped for
    # the layers across (which turn their halves apart too), cost the Vancouver tile at
    # 175 mm 2.2 s of its 16.
    candidates = []
    if twist and turn > 0:
        crossed = programmed(turn)
        candidates.append((crossed, lambda **kw: settle(crossed, **kw), TWIST_GAIN))
    stacks = []
    if across and cp.across_layers == "auto" and profile.layers >= 4:
        # On the layout solved again for the stack's shrink, and on the first one (relaid,
        # the saddles, the starfish and the elongated peak rest 40-80 % closer; three
        # islands and the small terrains 5-35 % further).
        stacks = [make.stack(relay, twist, bilayer) for relay in (True, False)]
        candidates += [(stack, make.counted(_settle_stack(mesh, stack, metric)), ACROSS_GAIN)
                       for stack, metric in stacks]
    if not candidates:
        return program, sim
    (program, kept_sim), tried = _tried(program, sim, candidates)
    first = len(candidates) - len(stacks)
    if first:
        program.twist = _comparison_twist(tried, sim, turn, crossed)
        if tried["kept"] and tried["chosen"] >= first:
            # With the layers across, the halves along d turn apart as the stack's twist needs.
            program.twist = dict(program.twist, kept=program.crossed, with_across=True)
    if stacks:
        program.across = _comparison_across(tried, sim, first, stacks[0][0].across["relaid"])
    return program, kept_sim


class Programs:
    """The programs :func:`simulate_free` chooses among for the layout ``flat`` of
    ``mesh``, made one at a time: the target's curvature read once (``K``), the shrink
    with room to bend (``sigma``) and the sheet's thickness (``thick``) shared by all."""

    def __init__(self, hf, mesh, flat, profile, tally=None, relief=None):
        self.mesh, self.flat, self.profile = mesh, flat, profile
        self.tally = [] if tally is None else tally
        lim = profile.shrink_limits
        self.cp = cp = profile.curvature
        # The printed sheet shrinks only within the material's range (the G-code clamps
        # the thickness the same way), so the simulation shrinks by the clamped sigma.
        laid = np.clip(flat.sigma, lim.s_min, lim.s_max)
        # One read of the target serves the first layout and every relaid one; its
        # curvature from ``relief`` where the plan gives one (:func:`curvature.relief`).
        self.derivs = curvature.surface_derivatives(hf if relief is None else relief,
                                                    curvature.PROGRAM_SMOOTH_MM)
        self.K = curvature.target_tensor(hf, mesh, flat, laid, derivs=self.derivs)
        # Where the layout leaves no shrink to bend with, a little is added along d.
        self.sigma = curvature.room_for(self.K, flat.direction, laid, self.thickness(laid),
                                        lim.s_min, lim.s_max, c=cp.bilayer_c,
                                        added_max=cp.max_added_shrink)
        self.thick = self.thickness(self.sigma)
        # Crossed groups need an even layer count: a middle layer printed with either
        # group would shear the sheet's mean shrink by twist / (2 * layers).
        self.turn = cp.turn_max_deg if profile.layers % 2 == 0 else 0.0

    def thickness(self, s):
        p = self.profile
        return thickness_for(s, p.shrink_curve, p.layers, p.thickness_mm.min,
                             p.thickness_mm.max)

    def programmed(self, turn_max_deg):
        """The bilayer along ``d`` (its groups turned apart up to ``turn_max_deg``): the
        lower layers shrink more where the target rises, so bending pulls toward the
        target instead of toward flat."""
        return _program_on(self.mesh, self.flat, self.profile, self.thickness, self.K,
                           self.sigma, turn_max_deg)

    def settle(self, prog, **kw):
        """``prog`` (along ``d`` on the first layout) settled: SimResult."""
        A, B = prog.group_tensors(self.flat.direction, self.sigma)
        mesh, xy = self.mesh, self.flat.xy
        sim = simulate_shell(mesh.vertices, mesh.faces, xy,
                             tensor_rest(xy, mesh.faces, (A + B) / 2), self.thick,
                             theta_rest=prog.theta_rest, pop=BATH_BUMP, **kw)
        self.tally.append(sim.iterations)
        return sim

    def counted(self, settle):
        """``settle`` with its iterations added to :attr:`tally`."""
        def counted(**kw):
            sim = settle(**kw)
            self.tally.append(sim.iterations)
            return sim
        return counted

    def stack(self, relay, twist, bilayer):
        """The stack with two layers across (:func:`_across_stack`): (program, metric)."""
        return _across_stack(self.derivs, self.mesh, self.flat, self.K, self.sigma,
                             self.profile, self.thickness, self.turn if twist else 0.0,
                             bilayer, relay)

    def chosen(self, which, twist=True):
        """The program ``which`` (:data:`CHOICES`) and ``settle(**kw)`` of its sheet."""
        bilayer = self.programmed(0.0)
        if which == "bilayer":
            return bilayer, lambda **kw: self.settle(bilayer, **kw)
        if which == "twist":
            crossed = self.programmed(self.turn)
            return crossed, lambda **kw: self.settle(crossed, **kw)
        stack, metric = self.stack(which == "across_relaid", twist, bilayer)
        return stack, self.counted(_settle_stack(self.mesh, stack, metric))


# What :func:`simulate_free` can settle on: the bilayer, its groups crossed by the twist,
# two layers across on the relaid layout, or on the first.
CHOICES = ("bilayer", "twist", "across_relaid", "across_first")


def choice_of(program):
    """Which of :data:`CHOICES` ``program`` (from :func:`simulate_free`) is."""
    if program.across is not None and program.across["kept"]:
        return "across_relaid" if program.across["chosen"] == 0 else "across_first"
    if program.twist is not None and program.twist["kept"]:
        return "twist"
    return "bilayer"


def _comparison_twist(tried, sim, turn, crossed):
    """The report's ``twist``: the crossed groups' probe (or rest, where they went on)
    against the bilayer at rest; the twist is candidate 0 of :func:`_tried`."""
    mine = tried["chosen"] == 0
    return {"kept": bool(mine and tried["kept"]), "turn_max_deg": float(turn),
            "crossed_mean_displacement_mm": (tried["tried_mean_displacement_mm"] if mine
                                             else tried["probe_mean_displacement_mm"][0]),
            "crossed_at_rest": bool(mine and tried["tried_at_rest"]),
            "along_mean_displacement_mm": float(sim.mean_displacement_mm),
            "crossing_deg": crossed.crossing_deg()}


def _comparison_across(tried, sim, first, relaid):
    """The report's ``across``: the two stacks (relaid, then on the first layout) from
    candidate ``first`` of :func:`_tried` on, ``chosen`` the one probed closer."""
    probes = tried["probe_mean_displacement_mm"][first:]
    mine = tried["chosen"] >= first
    chosen = tried["chosen"] - first if mine else int(np.argmin(probes))
    return {"kept": bool(mine and tried["kept"]),
            "tried_mean_displacement_mm": (tried["tried_mean_displacement_mm"] if mine
                                           else probes[chosen]),
            "tried_at_rest": bool(mine and tried["tried_at_rest"]),
            "before_mean_displacement_mm": float(sim.mean_displacement_mm),
            "chosen": chosen, "probe_mean_displacement_mm": probes,
            "relaid": dict(relaid, chosen=chosen == 0)}


def _settle_stack(mesh, stack, metric):
    """``settle(**kw)`` of a stack with two layers across on its own layout."""
    laid = stack.layout

    def settle(**kw):
        return simulate_shell(mesh.vertices, mesh.faces, laid.xy,
                              tensor_rest(laid.xy, mesh.faces, metric),
                              stack.laminate.thickness_mm, theta_rest=stack.theta_rest,
                              pop=BATH_BUMP, **kw)
    return settle


def _across_stack(derivs, mesh, flat, K, sigma, profile, thickness, turn, bilayer,
                  relay=True):
    """The program with two layers across ``d`` (:mod:`pipeline.layout.laminate`), on
    the layout solved again for the shrink that stack prints (:func:`_relaid_for`,
    :data:`RELAY_PASSES` times), the stack made again on each. Printed on the first
    layout the stack's own shrink put the sheet off the target's metric; relaid once, the
    starfish rests 0.11 % of its diameter off instead of 0.54 %, the elongated peak 0.25
    instead of 0.39 %, the hyperbolic paraboloid 0.06 instead of 0.35 % (each settled
    from flat; the smoothed coast tile 0.54 against 0.48 %). Without ``relay`` the stack
    is made on the first layout, its layers along ``d`` those of ``bilayer`` (the program
    already made there).
    ``derivs``: the target's :func:`pipeline.layout.curvature.surface_derivatives`.
    Returns (program with ``layout`` and ``across = {"relaid": ...}``, its mean shrink
    tensor (m, 2, 2))."""
    lim, cp, n = profile.shrink_limits, profile.curvature, profile.layers

    def stack_on(K_, d, s):
        return across_laminate(K_, d, s, lambda x: thickness(x) / n, n, lim.s_min, lim.s_max,
                               cp.bilayer_c, turn_max_deg=turn, c_across=cp.across_constant)
    laid, info = flat, None
    for _ in range(RELAY_PASSES if relay else 0):
        d = np.asarray(laid.direction, dtype=float)
        new, info = _relaid_for(stack_on(K, d, sigma).metric(d), laid, mesh, lim)
        if new is laid:
            break
        laid = new
        s_laid = np.clip(laid.sigma, lim.s_min, lim.s_max)
        K = curvature.target_tensor(None, mesh, laid, s_laid, derivs=derivs)
        sigma = curvature.room_for(K, laid.direction, s_laid, thickness(s_laid), lim.s_min,
                                   lim.s_max, c=cp.bilayer_c, added_max=cp.max_added_shrink)
    lam = stack_on(K, laid.direction, sigma)
    base = bilayer if laid is flat else _program_on(mesh, laid, profile, thickness, K, sigma)
    stack = _across_program(base, lam, laid, mesh.faces, cp.bilayer_c,
                            c_across=cp.across_constant)
    stack.layout, stack.across = laid, {"relaid": info}
    return stack, lam.metric(laid.direction)


def _relaid_for(metric, laid, mesh, lim):
    """The layout ``laid`` solved again for the stack's mean shrink ``metric`` ((m, 2, 2)):
    held across ``d``, along ``d`` at least what the stack shrinks there (the layout's
    and the room; the starfish rests at 0.10 % so, at 0.15 % with only the room held).
    Returns (the new layout, or ``laid`` itself where the new one would fold; the solve's
    figures)."""
    import dataclasses

    from pipeline.geometry import quarter_turn
    from pipeline.layout.compensate import relaid
    d = np.asarray(laid.direction, dtype=float)
    e = quarter_turn(d)
    xy, d2, s2, info = relaid(mesh.vertices, mesh.faces, laid.xy, d,
                              np.einsum("mi,mij,mj->m", e, metric, e),
                              np.einsum("mi,mij,mj->m", d, metric, d), lim.s_min, lim.s_max)
    info["flipped"] = int(np.count_nonzero(signed_areas_2d(xy, mesh.faces) <= 0))
    info = {k: (round(v, 6) if isinstance(v, float) else v) for k, v in info.items()}
    if info["flipped"]:
        return laid, info       # a folded layout prints nothing: the stack stays
    return dataclasses.replace(laid, xy=xy, direction=d2, sigma=s2), info


def _program_on(mesh, laid, profile, thickness, K, sigma, turn_max_deg=0.0):
    """The layer program along ``d`` of the layout ``laid`` (a FreeLayout) whose shrink,
    with room, is ``sigma``: the bilayer, its groups turned apart up to ``turn_max_deg``
    for the twist, and the shrink the room added (``added``)."""
    lim, cp = profile.shrink_limits, profile.curvature
    prog = curvature.program(K, mesh.faces, laid.xy, laid.direction, sigma, thickness(sigma),
                             lim.s_min, lim.s_max, c=cp.bilayer_c, turn_max_deg=turn_max_deg)
    prog.added = _added(laid.xy, mesh.faces, np.clip(laid.sigma, lim.s_min, lim.s_max), sigma)
    return prog


def _tried(program, sim, candidates):
    """Settle each of ``candidates`` ([(program, ``settle(start=, iterations=)`` its
    sheet, gain)]) from ``sim``'s shape for a probe of :data:`PROBE_ITERATIONS`; the one
    whose probe comes closest against its gain (the fraction closer than ``sim`` it must
    rest to be kept) goes on to rest if its probe is already that much closer, and is
    kept if it rests so. Returns ((program, sim) kept, the comparison: ``chosen`` the
    index of that candidate, ``probe_mean_displacement_mm`` of each)."""
    probes = [settle(start=sim.vertices, iterations=PROBE_ITERATIONS)
              for _, settle, _ in candidates]
    need = [(1.0 - gain) * sim.mean_displacement_mm for _, _, gain in candidates]
    chosen = int(np.argmin([p.mean_displacement_mm / max(n, 1e-300)
                            for p, n in zip(probes, need)]))
    (other, settle, _), probe = candidates[chosen], probes[chosen]
    tried = probe
    if probe.mean_displacement_mm < need[chosen]:
        tried = _continued(settle(start=probe.vertices), sim, probe)
    kept = tried.mean_displacement_mm < need[chosen]
    comparison = {"kept": bool(kept),
                  "tried_mean_displacement_mm": float(tried.mean_displacement_mm),
                  "tried_at_rest": tried is not probe,
                  "before_mean_displacement_mm": float(sim.mean_displacement_mm),
                  "chosen": chosen,
                  "probe_mean_displacement_mm": [float(p.mean_displacement_mm) for p in probes]}
    return ((other, tried) if kept else (program, sim)), comparison


def _across_program(bilayer, lam, flat, faces, c, c_across=None):
    """``bilayer`` (the program along ``d``) with its layers as the laminate ``lam``
    prints them: the inner layers' bilayer along ``d``, the rest angles of the whole
    stack's curvature, ``lam`` attached."""
    import dataclasses
    d = np.asarray(flat.direction, dtype=float)
    inner = lam.layer_sigma[:, ~lam.across]
    half = inner.shape[1] // 2
    K = lam.curvature(d, c, c_across=c_across)
    zero = np.zeros(len(d))
    return dataclasses.replace(
        bilayer, delta_sigma=inner[:, :half].mean(axis=1) - inner[:, half:].mean(axis=1),
        kappa=np.einsum("mi,mij,mj->m", d, K, d),
        theta_rest=curvature.rest_angles(flat.xy, faces, lam.metric(d), K), laminate=lam,
        turn_bottom=lam.turn_bottom if lam.turned else zero,
        turn_top=lam.turn_top if lam.turned else zero)


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
    area = np.abs(signed_areas_2d(xy, faces))
    return {"area_fraction": float(area[sigma > laid].sum() / max(area.sum(), 1e-12)),
            "max": float((sigma - laid).max(initial=0.0))}
