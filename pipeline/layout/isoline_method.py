"""The paper's layout method, ``isoline``: an isoline mesh, its layout, the simulation
of that sheet and paths along the isolines. One of the methods
:func:`pipeline.layout.method.method_for` finds by name; ``free_method`` is the other.
"""

import time
from pathlib import Path

import numpy as np

from pipeline import alternatives
from pipeline.geometry import on_bed
from pipeline.layout.isoline import flatten
from pipeline.meshing.isoline import build_mesh
from pipeline.paths.isoline import plan_toolpaths
from pipeline.problems import fold_area_fraction, layout_problems, simulation_problems
from pipeline.simulation.forward import simulate
from pipeline.simulation.resample import onto_grid
from pipeline.simulation.shell import directional_rest, simulate_shell, thickness_for


class IsolineMethod:
    """The stages of a plan by the paper's method (see :mod:`pipeline.layout.method`)."""

    name = "isoline"
    other = "free"
    # Named in the progress line that asks whether this method would form a plan the
    # other one could not print.
    title = "paper's (isoline)"
    # The relief is planned as given: nothing is fitted, so no smoothing can make it hold.
    hold_look = False

    def prepare(self, result, hf, profile, sidecar, opts, stage, timing, force_fit):
        """The height field to plan: ``hf`` as validated (this method fits nothing)."""
        return hf

    def sheet(self, result, hf, profile, path, stage, timing, opts):
        """Isoline mesh, isoline layout, its simulation, paths along the isolines: fills
        ``result.mesh``, ``flat``, ``sim``, ``xy_bed`` (mm), ``toolpaths``,
        ``fold_fraction`` and the problems of each."""
        mp = profile.mesh
        t = stage("mesh", "isolines every %.3g mm, gradient lines every %.3g mm"
                  % (mp.isoline_step_mm, mp.gradient_spacing_mm))
        mesh = build_mesh(hf, isoline_step_mm=mp.isoline_step_mm,
                          gradient_spacing_mm=mp.gradient_spacing_mm, l_u_mm=mp.l_u_mm,
                          l_sim_mm=mp.l_sim_mm)
        result.mesh = mesh
        timing["mesh"] = time.perf_counter() - t

        fp = profile.flatten
        lim = profile.shrink_limits
        t = stage("flatten", "%d triangles, up to %d iterations"
                  % (len(mesh.faces), fp.iterations))
        weights = fp.weights()
        flat = flatten(mesh, s_min=lim.s_min, s_max=lim.s_max, iterations=fp.iterations,
                       weights=weights)
        result.flat = flat
        timing["flatten"] = time.perf_counter() - t
        # A folded layout is not bad input: the plan goes on so the pictures show where,
        # but where the fold covers more than a sliver of the sheet it is marked not
        # printable (the daemon will not print it); a few flipped triangles at the edge
        # only make paths overlap in a spot.
        result.fold_fraction = fold_area_fraction(flat.xy, mesh.faces)
        result.problems += layout_problems(flat, result.fold_fraction, lim,
                                           Path(path).stem + ".yaml", opts["smooth_mm"])

        t = stage("simulate", "forward simulation of the flat sheet (%s)"
                  % ("thin shell" if fp.simulation == "shell" else "the paper's"))
        # The printed sheet can only shrink within the material's range (the G-code clamps
        # the thickness the same way), so the simulation shrinks by the clamped sigma.
        if fp.simulation == "shell":
            sheet = onto_grid(hf, mesh, flat.xy, mp.grid_mm)
            sigma = np.clip(sheet.sigma, lim.s_min, lim.s_max)
            thick = thickness_for(sigma, profile.shrink_curve, profile.layers,
                                  profile.thickness_mm.min, profile.thickness_mm.max)
            sim = simulate_shell(sheet.vertices, sheet.faces, sheet.xy,
                                 directional_rest(sheet.xy, sheet.faces, sheet.direction, sigma),
                                 thick, clamped=int(np.count_nonzero(sigma != sheet.sigma)))
        else:
            sim = simulate(mesh, flat, weights={k: weights[k] for k in
                                                ("bridge", "printing", "bending", "shear")},
                           s_min=lim.s_min, s_max=lim.s_max)
        result.sim = sim
        result.problems += simulation_problems(sim)
        timing["simulate"] = time.perf_counter() - t

        t = stage("toolpath", "paths %.3g mm wide" % profile.path_width_mm)
        result.xy_bed = on_bed(flat.xy, profile.bed_mm)
        tp = profile.toolpath
        result.toolpaths = plan_toolpaths(
            result.xy_bed, mesh.faces, mesh.vertex_level, mesh.printing_edges, flat.sigma,
            profile.path_width_mm, merge_angle_deg=tp.merge_angle_deg, merge_sigma=tp.merge_sigma)
        timing["toolpath"] = time.perf_counter() - t

    def after(self, result, hf, profile, sidecar, opts, timing):
        """Nothing: a height the sidecar asks for is planned as asked."""

    def would(self, hf, profile):
        """The quick look at whether this method would form ``hf``: the report's
        ``other_method`` section of a plan by the other method."""
        return alternatives.isoline_would(hf, profile)


ISOLINE = IsolineMethod()
