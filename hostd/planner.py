"""Run the pipeline on one file and write its outputs (used by `hostd plan` and the daemon).

Outputs for input ``NAME.*`` (all published together, see ``hostd.outputs``): the files
:func:`output_names` lists (report, G-code, flat and simulated meshes, pictures, and with
colour the texture and its outline), the one list the writer and ``hostd plan --help``
take their names from. On a pipeline error only ``NAME.error.json`` is written.
"""

import json
import math
import shutil
import time
from pathlib import Path

import numpy as np

from hostd import kept
from hostd.outputs import Staging, atomic_write, json_text, output_names
from pipeline import plyio
from pipeline.gcode import writer as gcode
from pipeline.gcode.link import LINK_SHARE
from pipeline.pictures import figure, hfimage, render, texture
from pipeline.errors import PipelineError, PlanError
from pipeline.plan import plan_file
from pipeline.problems import BLOCKING
from pipeline.simulation import fidelity

TEXTURE_DPI = 300


def run(input_path, profile, outdir, progress=None, force_fit=False, method=None, keep=None):
    """Plan ``input_path`` into ``outdir``.

    Returns the :class:`pipeline.plan.Plan`. On a :class:`PipelineError`,
    writes ``NAME.error.json`` (atomically) and re-raises. ``keep``: a folder of the
    node's own where the G-code and report are written first, ``outdir`` getting copies
    (see :mod:`hostd.kept`).
    """
    input_path = Path(input_path)
    outdir = Path(outdir)
    name = input_path.stem
    try:
        plan = plan_file(input_path, profile, progress=progress, force_fit=force_fit,
                         method=method)
        if progress:
            progress("write", "rendering pictures and writing outputs")
        t = time.perf_counter()
        with Staging(outdir) as st:
            write_outputs(st, plan, keep)
            plan.report["timing_s"]["write"] = round(time.perf_counter() - t, 4)
            report = json_text(plan.report)
            if keep:
                atomic_write(Path(keep) / kept.REPORT, report)
            st.write(output_names(name)["report.json"], report)
        stale = outdir / (name + ".error.json")
        if stale.exists():
            stale.unlink()
        return plan
    except PipelineError as exc:
        atomic_write(outdir / (name + ".error.json"),
                     json_text(dict(exc.to_dict(), input=input_path.name,
                                    profile=getattr(profile, "name", None))))
        raise


def write_outputs(st, plan, keep=None):
    """Render and write every file of ``plan`` into the staging area ``st``.

    Adds the report's ``gcode`` section and the ``gcode``/``texture`` timings. With
    ``keep`` the G-code is written there and ``st`` gets a copy.
    """
    name, mesh, flat, sim, prof = plan.name, plan.mesh, plan.flat, plan.sim, plan.profile
    # Every file's name comes from output_names (a KeyError for one it does not list),
    # so `hostd plan --help`, which lists them from there, cannot miss one.
    out = output_names(name, color=plan.hf.color is not None)
    lim = prof.shrink_limits
    timing = plan.report["timing_s"]
    tp = plan.toolpaths
    t = time.perf_counter()
    gcode_path = Path(keep) / kept.GCODE if keep else st.path(out["gcode"])
    try:
        stats = _write_gcode(plan, gcode_path)
    except PlanError as e:
        raise _blocked_first(plan, e) from e
    if plan.blocked:
        _mark_not_printable(gcode_path, plan.problems)
    if keep:
        shutil.copyfile(gcode_path, st.path(out["gcode"]))
    timing["gcode"] = round(time.perf_counter() - t, 4)
    plan.report["gcode"] = _gcode_report(stats)
    for problem in link_problems(stats, prof):
        plan.problems.append(problem)
        plan.report.setdefault("warnings", []).append(problem)
    t = time.perf_counter()
    if plan.hf.color is not None:
        colors = texture.vertex_colors(plan.hf, mesh.vertices)
        image, info = texture.texture_image(mesh.vertices, mesh.faces, plan.xy_bed, colors,
                                            dpi=TEXTURE_DPI)
        texture.save_texture(image, st.path(out["texture.png"]), dpi=TEXTURE_DPI)
        st.write(out["outline.svg"], texture.outline_svg(
            plan.xy_bed, mesh.faces, info["marks"], info["margin_mm"], dpi=TEXTURE_DPI))
        plan.report["texture"] = {"dpi": TEXTURE_DPI, "size_px": list(info["size_px"]),
                                  "opacity": info["opacity"], "marks": info["marks"]}
    timing["texture"] = round(time.perf_counter() - t, 4)
    travel = [(a[-1], b[0]) for a, b in zip(tp.traces[:-1], tp.traces[1:])]
    st.write_image(out["toolpath.png"], render.toolpath_image(
        tp.traces, tp.sigma, lim.s_min, lim.s_max, prof.path_width_mm,
        travel=np.array(travel) if travel else None,
        title=_toolpath_title(plan), dry=tp.dry))
    flat3 = np.column_stack([flat.xy, np.zeros(len(flat.xy))])
    plyio.write_ply(st.path(out["flat.ply"]), flat3, mesh.faces)
    disp = sim.displacement_mm
    vmax = max(float(np.ceil(disp.max())), 1.0)
    colors = figure.colormap(disp, 0.0, vmax, name="displacement")
    # The sheet may have been simulated on a grid of its own rather than the plan's mesh.
    sim_faces = mesh.faces if sim.faces is None else sim.faces
    target = mesh.vertices if sim.target is None else sim.target
    plyio.write_ply(st.path(out["simulated.ply"]), sim.vertices, sim_faces,
                    vertex_colors=colors)
    if hasattr(flat, "direction"):
        st.write_image(out["stress.png"], render.direction_image(
            flat.xy, mesh.faces, flat.direction, flat.sigma, lim.s_min, lim.s_max,
            title="%s: flat layout, shrink and print direction per triangle" % name))
    else:
        st.write_image(out["stress.png"], render.stress_image(
            flat.xy, mesh.printing_edges, flat.sigma, lim.s_min, lim.s_max, faces=mesh.faces,
            title="%s: flat layout, shrink per printing edge" % name))
    # The file as given beside the sheet, the target planned (smoothed, lowered) third.
    given, sheet, off = fidelity.against_given(sim.vertices, target, plan.validated)
    st.write_image(out["preview.png"], render.preview_image(
        target, sim_faces, sheet, off, title=preview_title(plan),
        inverted_faces=plan.inverted["faces"] if plan.inverted else None,
        given_vertices=given, target_label=_target_label(plan)))
    removed = plan.simplified.get("removed_peaks", [])
    count = int(plan.simplified.get("removed_count", len(removed)))
    st.write_image(out["input.png"], hfimage.heightfield_image(
        plan.hf.z, removed_peaks=removed, pixel_mm=plan.hf.pixel_mm,
        title="%s: input as meshed (%d small peaks removed%s)" % (name, count, _input_note(plan)),
        isoline_step_mm=prof.mesh.isoline_step_mm, removed_count=count,
        removed_mm=getattr(plan.fit, "removed_map", None) if plan.fit is not None else None))


def link_problems(stats, profile):
    """A warning when the file's moves need more of the serial link than a print may use:
    what the printer host will do about it and what would print at full speed."""
    pct = stats.get("feed_percent", 100)
    if pct >= 100:
        return []
    speed = profile.speeds_mm_s.print
    baud = stats["link_baud"]
    return [{"code": "gcode.link_too_slow",
             "message": "the file asks %.0f moves/s at the print speed of %g mm/s, more than "
                        "%d %% of the %.0f lines/s a %d-baud link carries: the printer would "
                        "stop between moves and blob; the printer host runs this job at %d %% "
                        "feed" % (stats["moves_per_s"], speed, round(100 * LINK_SHARE),
                                  stats["link_moves_per_s"], baud, pct),
             "fix": "print at full speed with serial.baud: %d in the profile (and the "
                    "printer's firmware), or set speeds_mm_s.print to %g; or turn on arcs "
                    "(toolpath.arc_tolerance_mm: 0.02, Marlin's ARC_SUPPORT)" % (
                        _baud_for(baud, 100.0 / pct), math.floor(speed * pct) / 100.0)}]


def _baud_for(baud, factor):
    """The smallest common baud rate at least ``baud * factor``."""
    rates = (115200, 230400, 250000, 460800, 500000, 921600, 1000000)
    return next((r for r in rates if r >= baud * factor), rates[-1])


def preview_title(plan):
    """The preview's title: the job, its size, the layout method that planned it, and
    what the fit did to make it form (the smoothing, or the relief it was lowered to)."""
    return "%s (%.0f mm, %s method): target vs. simulated after shrinking%s" % (
        plan.name, plan.report["heightfield"]["longest_diameter_mm"],
        plan.report["flatten"]["method"], _fit_note(plan))


def _input_note(plan):
    """What the fit did to the input before it was meshed, and which side of a mesh was
    taken as up: '' or ', ...'."""
    up = getattr(plan.input_hf, "up", None) if getattr(plan, "input_hf", None) else None
    note = (", mesh read with %s up (%s)" % (up["up"], "sidecar" if up["chosen"] == "sidecar"
                                              else "its height-field side") if up else "")
    return note + _fit_input_note(plan)


def _fit_input_note(plan):
    fit = getattr(plan, "fit", None)
    if fit is not None and fit.applied_smooth_mm is not None:
        return ", smoothed %g mm by the fit" % fit.applied_smooth_mm
    if fit is not None and fit.applied_scale < 1.0:
        return ", relief lowered to %.0f %% by the fit" % (100 * fit.applied_scale)
    return ""


def _target_label(plan):
    """The preview's third view: the target planned, and what the fit did to the file."""
    note = _fit_input_note(plan)
    return "planned target" + (" (%s)" % note[2:] if note else "")


def _fit_note(plan):
    fit = getattr(plan, "fit", None)
    if fit is not None and fit.applied_smooth_mm is not None:
        return " (smoothed %g mm to form, the surface moved %.1f mm on average)" % (
            fit.applied_smooth_mm, fit.removed_mm or 0.0)
    if fit is None or fit.applied_scale >= 1.0:
        return ""
    return " (relief lowered from %.1f to %.1f mm to form)" % (fit.requested_height_mm,
                                                              fit.max_height_mm)


def _toolpath_title(plan):
    """The tool-path picture draws one layer's paths: with crossed layer groups, the lower
    group's, and the title says what the upper layers print instead."""
    up = getattr(plan, "upper_toolpaths", None)
    across = getattr(plan, "across_toolpaths", None)
    if across is not None:
        layers = {k: " and ".join(map(str, v)) for k, v in plan.curvature.laminate.groups().items()}
        return ("%s: tool paths of layers %s, shrink per segment (layers %s: %s across "
                "them%s)" % (plan.name, layers["lower"], layers["across"],
                             figure.counted(len(across.traces), "trace"),
                             "" if up is None else "; layers %s: %d of their own, turned apart"
                             % (layers["upper"], len(up.traces))))
    if up is None:
        return "%s: tool paths, shrink per segment" % plan.name
    return ("%s: lower layers' tool paths, shrink per segment (the upper layers print %s "
            "of their own, turned up to %.0f degrees apart)"
            % (plan.name, figure.counted(len(up.traces), "trace"),
               plan.curvature.crossing_deg()["max"]))


def _write_gcode(plan, path):
    """Write the plan's G-code to ``path``: its paths with their bilayer, the upper layer
    group's own paths, and the paths of the layers across them. Returns the stats."""
    tp, up = plan.toolpaths, getattr(plan, "upper_toolpaths", None)
    across = getattr(plan, "across_toolpaths", None)
    if across is not None:
        lam = plan.curvature.laminate
        groups = lam.groups()
        sets = [("across", across)] + ([("upper", up)] if up is not None else [])
        shrink = _per_segment(plan, lam.layer_sigma, tp.traces, *[p.traces for _, p in sets])
        return gcode.write_laminate_gcode(
            (tp.traces, shrink[0], tp.dry),
            [(paths.traces, per, groups[role], role, paths.dry)
             for (role, paths), per in zip(sets, shrink[1:])],
            plan.profile, path, name=plan.name, center=False)
    prog = getattr(plan, "curvature", None)
    deltas = (_per_segment(plan, prog.delta_sigma, tp.traces, *([up.traces] if up else []))
              if prog is not None else [None, None])
    return gcode.write_gcode(
        tp.traces, tp.sigma, plan.profile, path, name=plan.name, center=False,
        deltas=deltas[0], upper=(up.traces, up.sigma, deltas[1], up.dry) if up else None,
        dry=tp.dry)


def _per_segment(plan, per_triangle, *trace_sets):
    """``per_triangle`` ((m, ...) a value of each triangle) at each segment of each set
    of traces, from the triangle it crosses (its midpoint's nearest triangle centre):
    one list of (k_i - 1, ...) arrays per set."""
    from scipy.spatial import cKDTree
    tree = cKDTree(plan.xy_bed[plan.mesh.faces].mean(axis=1))
    out = []
    for traces in trace_sets:
        found = []
        for p in traces:
            p = np.asarray(p, dtype=float)
            found.append(per_triangle[tree.query((p[1:] + p[:-1]) / 2)[1]])
        out.append(found)
    return out


def _blocked_first(plan, error):
    """The error to report when a plan's G-code cannot be written: a blocked plan's own
    reason and fix, with the G-code's error after them. A relief too high to form lays
    out larger than it prints, so its G-code may leave the bed; the fix that helps is
    the relief's (the sidecar line), not a smaller model."""
    blocking = [p for p in plan.problems if p["code"] in BLOCKING]
    if not blocking:
        return error
    first = blocking[0]
    # No report is written without G-code: the other method's answer goes with the error.
    other = [p["message"] for p in plan.problems if p["code"] == "plan.other_method"]
    return PlanError("%s; besides, its G-code cannot be written: %s%s" % (
                         first["message"], error.message, "".join("; " + m for m in other)),
                     code=first["code"], fix=first["fix"],
                     details={"gcode": {"code": error.code, "message": error.message,
                                        "where": error.where, **error.details},
                              "other_method": plan.report.get("other_method")})


def _mark_not_printable(path, problems):
    """Put the reasons at the top of the G-code, where a person or host sees them first."""
    head = "".join("; WARNING NOT PRINTABLE: %s: %s\n" % (p["code"], p["message"])
                   for p in problems if p["code"] in BLOCKING)
    body = path.read_bytes()
    path.write_bytes(head.encode("utf-8") + body)


def _gcode_report(stats):
    keys = ("lines", "bytes", "layers", "thickness_mm", "clamped_segments", "filament_mm",
            "estimated_print_s", "bed_fits")
    out = {k: stats[k] for k in keys}
    out.update({k: v for k, v in stats.items() if k not in out})
    return json.loads(json.dumps(out, default=float))
