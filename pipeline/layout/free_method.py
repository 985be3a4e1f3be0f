"""The free layout method: a plain mesh, a layout whose print direction each triangle
chooses, the thin-shell simulation of that sheet with its curvature program, and stripe
paths along it; the relief is fitted to what forms. One of the methods
:func:`pipeline.layout.method.method_for` finds by name; ``isoline_method`` is the other.
"""

import time

from pipeline import alternatives, fitting
from pipeline.geometry import on_bed, quarter_turn
from pipeline.layout import curvature
from pipeline.layout.free import FREE_BELOW, flatten_free, forget_systems
from pipeline.layout.reach import reach
from pipeline.meshing.grid import build_grid_mesh
from pipeline.paths.sheet import Sheet
from pipeline.paths.stripes import stripe_toolpaths
from pipeline.problems import fold_area_fraction, free_layout_problems, simulation_problems
from pipeline.simulation.staged import simulate_free


class FreeMethod:
    """The stages of a plan by the free method (see :mod:`pipeline.layout.method`)."""

    name = "free"
    other = "isoline"
    # Named in the progress line that asks whether this method would form a plan the
    # other one could not print.
    title = "free"
    # A free sheet that ends too far from the shape may hold it smoothed more: the
    # report's ``hold`` looks for the least smoothing that does.
    hold_look = True

    def prepare(self, result, hf, profile, sidecar, opts, stage, timing, force_fit):
        """The height field to plan: ``hf`` fitted to what forms where nobody asked for a
        height (:func:`pipeline.fitting.fitted`, which sets ``result.fit``)."""
        return fitting.fitted(result, hf, profile, sidecar, opts, stage, timing, force_fit)

    def sheet(self, result, hf, profile, path, stage, timing, opts):
        """The free print direction: a plain mesh, a layout whose direction each triangle
        chooses, the thin-shell simulation of that sheet, and stripe paths along it: fills
        ``result.mesh``, ``flat``, ``reach``, ``curvature``, ``sim``, ``xy_bed`` (mm),
        ``toolpaths`` (and ``upper_toolpaths``, ``across_toolpaths`` where the program
        prints those), ``fold_fraction`` and the problems of each."""
        mp, fp, lim = profile.mesh, profile.flatten, profile.shrink_limits
        t = stage("mesh", "a plain triangulation every %.3g mm" % mp.grid_mm)
        # The fit solved this very layout (the lowered relief, this mesh, these iterations)
        # on its last step: take it rather than solve it again.
        fit = result.fit
        reuse = fit.layout if fit is not None and fit.applied_scale < 1.0 else None
        mesh = reuse[0] if reuse else build_grid_mesh(hf, mp.grid_mm)
        result.mesh = mesh
        timing["mesh"] = time.perf_counter() - t
        t = stage("flatten", "%d triangles, free direction, up to %d iterations%s"
                  % (len(mesh.faces), fp.free_iterations, ", solved by the fit" if reuse else ""))
        flat = reuse[1] if reuse else flatten_free(mesh, lim.s_min, lim.s_max,
                                                   iterations=fp.free_iterations)
        # Only curvature along the paths can be programmed: where the layout leaves the
        # direction free, the paths turn the way the target bends most.
        # The directions turn as the relief the program reads bends (finer than the target
        # where the plan smoothed it); the reach reported is the target's.
        relief = hf if result.relief is None else result.relief
        flat = curvature.bend_free_directions(relief, mesh, flat, FREE_BELOW)
        result.flat = flat
        result.reach = reach(hf, mesh, flat, profile)
        timing["flatten"] = time.perf_counter() - t
        result.fold_fraction = fold_area_fraction(flat.xy, mesh.faces)
        result.problems += free_layout_problems(flat, result.fold_fraction)
        t = stage("simulate", "forward simulation of the flat sheet (thin shell)")
        result.curvature, sim = simulate_free(hf, mesh, flat, profile, relief=result.relief)
        result.sim = sim
        result.problems += simulation_problems(sim)
        timing["simulate"] = time.perf_counter() - t
        # The layouts are solved: their factored systems (~45 MB on a 248 mm terrain) would
        # only sit under the tool paths' own peak.
        forget_systems()
        t = stage("toolpath", "stripes %.3g mm wide along the print direction"
                  % profile.path_width_mm)
        # The layers across are printed on the layout solved again for their shrink: the
        # sheet, its pictures and its files are that layout's.
        flat = result.flat = result.curvature.layout or flat
        result.xy_bed = on_bed(flat.xy, profile.bed_mm)
        tp = profile.toolpath
        # The shrink as printed: the layout's, with what the curvature program added.
        sigma = result.curvature.sigma
        # Crossed layer groups print their own stripes; the lower group's are the plan's
        # paths (pictures, screen print), the upper group's are printed above them.
        sheet = Sheet(result.xy_bed, mesh.faces)

        def stripes(direction, shrink=sigma):
            return stripe_toolpaths(result.xy_bed, mesh.faces, direction, shrink,
                                    profile.path_width_mm, merge_angle_deg=tp.merge_angle_deg,
                                    merge_sigma=tp.merge_sigma, level=mesh.vertex_level,
                                    join_factor=tp.hop_reach_widths,
                                    over_factor=tp.hop_over_widths, sheet=sheet,
                                    rim_tail_factor=tp.rim_tail_widths)
        lower, upper = result.curvature.group_directions(flat.direction)
        result.toolpaths = stripes(lower)
        result.upper_toolpaths = stripes(upper) if result.curvature.crossed else None
        lam = result.curvature.laminate
        if lam is not None:
            # The layers across print stripes a quarter turn from the plan's.
            result.across_toolpaths = stripes(quarter_turn(flat.direction),
                                              lam.layer_sigma[:, lam.across].max(axis=1))
        timing["toolpath"] = time.perf_counter() - t

    def after(self, result, hf, profile, sidecar, opts, timing):
        """A height the sidecar asked for that does not form is refused
        (:func:`pipeline.fitting.refuse_too_high`)."""
        fitting.refuse_too_high(result, hf, profile, sidecar, opts, timing)

    def would(self, hf, profile):
        """The quick look at whether this method would form ``hf``: the report's
        ``other_method`` section of a plan by the other method."""
        return alternatives.free_would(hf, profile)


FREE = FreeMethod()
