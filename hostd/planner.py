"""Run the pipeline on one file and write its outputs (used by `hostd plan` and the daemon).

Outputs for input ``NAME.*`` (all published together, see ``hostd.outputs``):
``NAME.report.json``, ``NAME.flat.ply``, ``NAME.simulated.ply``,
``NAME.stress.png``, ``NAME.preview.png``, ``NAME.input.png``. On a pipeline error only
``NAME.error.json`` is written.
"""

import time
from pathlib import Path

import numpy as np

from hostd.outputs import Staging, atomic_write, json_text
from pipeline import figure, plyio, render
from pipeline.errors import PipelineError
from pipeline.plan import plan_file


def output_names(name):
    return {k: "%s.%s" % (name, k) for k in
            ("report.json", "flat.ply", "simulated.ply", "stress.png", "preview.png",
             "input.png")}


def run(input_path, profile, outdir, progress=None):
    """Plan ``input_path`` into ``outdir``.

    Returns the :class:`pipeline.plan.Plan`. On a :class:`PipelineError`,
    writes ``NAME.error.json`` (atomically) and re-raises.
    """
    input_path = Path(input_path)
    outdir = Path(outdir)
    name = input_path.stem
    try:
        plan = plan_file(input_path, profile, progress=progress)
        if progress:
            progress("write", "rendering pictures and writing outputs")
        t = time.perf_counter()
        with Staging(outdir) as st:
            write_outputs(st, plan)
            plan.report["timing_s"]["write"] = round(time.perf_counter() - t, 4)
            st.write(name + ".report.json", json_text(plan.report))
        stale = outdir / (name + ".error.json")
        if stale.exists():
            stale.unlink()
        return plan
    except PipelineError as exc:
        atomic_write(outdir / (name + ".error.json"),
                     json_text(dict(exc.to_dict(), input=input_path.name,
                                    profile=getattr(profile, "name", None))))
        raise


def write_outputs(st, plan):
    """Render and write every file of ``plan`` into the staging area ``st``."""
    name, mesh, flat, sim, prof = plan.name, plan.mesh, plan.flat, plan.sim, plan.profile
    lim = prof.shrink_limits
    flat3 = np.column_stack([flat.xy, np.zeros(len(flat.xy))])
    plyio.write_ply(st.path(name + ".flat.ply"), flat3, mesh.faces)
    disp = sim.displacement_mm
    vmax = max(float(np.ceil(disp.max())), 1.0)
    colors = figure.colormap(disp, 0.0, vmax, name="displacement")
    plyio.write_ply(st.path(name + ".simulated.ply"), sim.vertices, mesh.faces,
                    vertex_colors=colors)
    diameter = plan.report["heightfield"]["longest_diameter_mm"]
    st.write_image(name + ".stress.png", render.stress_image(
        flat.xy, mesh.printing_edges, flat.sigma, lim.s_min, lim.s_max, faces=mesh.faces,
        title="%s: flat layout, shrink per printing edge" % name))
    st.write_image(name + ".preview.png", render.preview_image(
        mesh.vertices, mesh.faces, sim.vertices, disp,
        title="%s (%.0f mm): target vs. simulated after shrinking" % (name, diameter)))
    removed = plan.simplified.get("removed_peaks", [])
    st.write_image(name + ".input.png", render.heightfield_image(
        plan.hf.z, removed_peaks=removed, pixel_mm=plan.hf.pixel_mm,
        title="%s: input as meshed (%d small peaks removed)" % (name, len(removed)),
        isoline_step_mm=prof.mesh.isoline_step_mm))
