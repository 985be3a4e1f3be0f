"""What the pipeline benchmarks' children run: Python source that ``pipeline.py``'s
``_child`` hands to a fresh interpreter pinned to one core (after ``import os, sys, json,
time, resource``). Each prints one JSON object as its last line.

- :data:`FLATTEN`: the isoline layout of the 175 mm dome at a given triangle count.
- :data:`PLAN`: a whole ``hostd plan`` of a file, each stage's wall and CPU seconds.
- :data:`SHAPE`: a reference shape saved as a height field and its sidecar.
- :data:`LAYOUT`: one layout method alone on a shape or a real tile.
- :data:`FINE_MAP`: a 16-megapixel 16-bit PNG height map and its sidecar.
"""

FLATTEN = r"""
from pipeline.input import shapes
from pipeline.meshing.isoline import build_mesh
from pipeline.layout.isoline import flatten
target = int(sys.argv[1])
hf = shapes.dome(diameter_mm=175.0, height_mm=33.0)
# Refine isoline step and l_u together (the paper's 1 mm : 0.25 mm), so triangles keep
# their shape and the count scales with 1 / l_u^2: one calibration mesh, then the real one.
n0 = len(build_mesh(hf, l_u_mm=1.0, isoline_step_mm=4.0, gradient_spacing_mm=8.0).faces)
lu = (n0 / target) ** 0.5
mesh = build_mesh(hf, l_u_mm=lu, isoline_step_mm=4.0 * lu, gradient_spacing_mm=8.0 * lu)
t = time.perf_counter()
res = flatten(mesh, iterations=50, tol=0.0)
dt = time.perf_counter() - t
print(json.dumps({"triangles": len(mesh.faces), "l_u_mm": round(lu, 3), "iterations": res.iterations,
                  "flatten_s": round(dt, 3), "setup_s": round(res.timing_s["setup"], 3),
                  "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}))
"""

PLAN = r"""
t_imp, c_imp = time.perf_counter(), time.process_time()
from pipeline.profiles.profile import load_profile
from hostd import planner
imports = {"wall_s": round(time.perf_counter() - t_imp, 3),
           "cpu_s": round(time.process_time() - c_imp, 3)}
path, outdir = sys.argv[1], sys.argv[2]
method = sys.argv[3] if len(sys.argv) > 3 else None
force_fit = "fit" in sys.argv[4:]
reference = os.environ.get("HOSTD_BENCH_REFERENCE")
prof = load_profile("generic-0.5mm")
if "shell" in sys.argv[4:]:
    import dataclasses
    prof = dataclasses.replace(prof, flatten=dataclasses.replace(prof.flatten, simulation="shell"))
# Each stage's wall and CPU time from the progress calls that open it (the plan's own
# timing_s is wall time only); the G-code inside the writing stage is clocked apart, so
# the pictures are what is left of it.
marks, gcode_cpu = [], [0.0, 0.0]
def progress(stage, message):
    marks.append((stage, time.perf_counter(), time.process_time()))
write_gcode = planner._write_gcode
def clocked(*a, **k):
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        return write_gcode(*a, **k)
    finally:
        gcode_cpu[0] += time.perf_counter() - t0
        gcode_cpu[1] += time.process_time() - c0
planner._write_gcode = clocked
settled = {}
if reference:
    # Keep what the plan's free settle was given, to settle its program again as the
    # reference does (the layout before any relaid one, the target, the mesh).
    import pipeline.layout.free_method as plan_mod
    fast_settle = plan_mod.simulate_free
    def keeping(*a, **k):
        settled["args"] = (a, k)
        return fast_settle(*a, **k)
    plan_mod.simulate_free = keeping
t = time.perf_counter()
plan = planner.run(path, prof, outdir, method=method, force_fit=force_fit, progress=progress)
marks.append(("end", time.perf_counter(), time.process_time()))
wall = time.perf_counter() - t
stages = {}
for (name, t0, c0), (_, t1, c1) in zip(marks[:-1], marks[1:]):
    was = stages.get(name, {"wall_s": 0.0, "cpu_s": 0.0})
    stages[name] = {"wall_s": was["wall_s"] + t1 - t0, "cpu_s": was["cpu_s"] + c1 - c0}
if "write" in stages:
    stages["gcode"] = {"wall_s": gcode_cpu[0], "cpu_s": gcode_cpu[1]}
    stages["pictures"] = {k: stages["write"][k] - gcode_cpu[i] for i, k in enumerate(("wall_s", "cpu_s"))}
    del stages["write"]
stages = {k: {kk: round(vv, 3) for kk, vv in v.items()} for k, v in stages.items()}
cpu_total = round(sum(v["cpu_s"] for v in stages.values()), 3)
r = plan.report
# The plan's own peak, before any reference settle adds to it.
peak_mb = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
ref = ref_cpu = None
if reference and "args" in settled:
    # The full-resolution settle of the program the plan chose, beside the plan's own
    # (fast) settle: "module:function" called as the plan called its settle, with
    # reference=True; it returns (program, SimResult).
    import importlib
    mod, fn = reference.split(":")
    a, k = settled["args"]
    c_ref = time.process_time()
    got = getattr(importlib.import_module(mod), fn)(*a, **dict(k, reference=True))[1]
    ref, ref_cpu = float(got.mean_displacement_mm), round(time.process_time() - c_ref, 3)
ts = r["timing_s"]
# The fit solves the plan's own layout (the flatten stage then reuses it): it counts.
to_sim = sum(ts.get(k, 0.0) for k in ("load", "validate", "fit", "mesh", "flatten", "simulate"))
every = ts["total"] + ts.get("gcode", 0.0) + ts.get("texture", 0.0)
g = r["gcode"]
fl, tp, fit = r["flatten"], r["toolpath"], r.get("fit") or {}
tips = None
if r["input"].startswith("starfish"):
    # The arms' tips: the target point farthest from the middle in each fifth of a turn.
    import numpy as np
    sim = plan.sim
    V = np.asarray(plan.mesh.vertices if sim.target is None else sim.target)
    c = V[:, :2] - V[:, :2].mean(axis=0)
    r2 = np.hypot(c[:, 0], c[:, 1])
    sector = ((np.arctan2(c[:, 1], c[:, 0]) + np.pi) / (2 * np.pi) * 5).astype(int) % 5
    tips = [round(float(sim.displacement_mm[np.flatnonzero(sector == k)[
        np.argmax(r2[sector == k])]]), 2) for k in range(5)]
hold = r.get("hold") or {}
print(json.dumps({
    "hold_smooth_mm": hold.get("smooth_mm"),
    "hold_displacement": next((t[1] for t in hold.get("tried", []) if t[0] == hold.get("smooth_mm")), None),
    "looks_s": round(ts.get("other_method", 0.0) + ts.get("hold", 0.0), 3),
    "method": fl.get("method"), "invalid_area_fraction": fl.get("invalid_area_fraction"),
    "flipped": fl.get("flipped", fl.get("flipped_triangles")), "fit_scale": fit.get("applied_scale"),
    "fit_max_height_mm": fit.get("max_height_mm"), "fit_s": ts.get("fit"),
    "fit_smooth_mm": fit.get("applied_smooth_mm"), "fit_removed_mm": fit.get("removed_mm"),
    "reach_p90": ((r.get("curvature") or {}).get("reach") or {}).get("p90"),
    "overlap": tp.get("overlap"), "direction_angle_deg": tp.get("direction_angle_deg"),
    "toolpath_gcode_s": round(ts.get("toolpath", 0.0) + ts.get("gcode", 0.0), 3),
    "link_moves_per_s": g.get("link_moves_per_s"), "arm_tips_mm": tips,
    "input": r["input"], "longest_diameter_mm": round(r["heightfield"]["longest_diameter_mm"], 1),
    "working_shape": r["heightfield"].get("working_shape"),
    "triangles": r["mesh"]["triangles"], "timing_s": ts, "load_to_simulation_s": round(to_sim, 3),
    "all_stages_s": round(every, 3),
    "wall_s": round(wall, 3),
    "invalid_edge_fraction": round(r["flatten"]["invalid_edge_fraction"], 4),
    "mean_displacement_mm": round(r["simulation"]["mean_displacement_mm"], 3),
    "mean_displacement_pct_of_diameter": round(100 * r["simulation"]["mean_displacement_fraction"], 3),
    "relief_mm": r["simulation"].get("relief_mm"),
    "mean_displacement_of_relief": r["simulation"].get("mean_displacement_of_relief"),
    "simulation_converged": r["simulation"]["converged"],
    "simulation_iterations": r["simulation"]["iterations"],
    "coarse_iterations": r["simulation"]["coarse_iterations"],
    "full_iterations": r["simulation"].get("full_iterations"),
    "simulated_vertices": r["simulation"]["sheet_vertices"],
    "traces": r["toolpath"]["traces"], "spacing_mm": r["toolpath"]["spacing_mm"],
    "ends_inside": r["toolpath"].get("ends_inside"),
    "ring_bridges": r["toolpath"].get("ring_bridges"),
    "rim_tails": r["toolpath"].get("rim_tails"), "rim_tail_mm": r["toolpath"].get("rim_tail_mm"),
    # The lower layers' hops printing over paths (third ones, or back over their own),
    # as a share of the path length: plastic printed twice that overlap does not see.
    "hop_overprint_share": (None if "hop_overprint_mm" not in r["toolpath"] else round(
        (r["toolpath"]["hop_overprint_mm"] + r["toolpath"].get("hop_overprint_own_mm", 0.0))
        / max(r["toolpath"]["length_mm"], 1e-9), 4)),
    # How much of it the nozzle moves over without extruding.
    "hop_dry_share": (None if "dry_mm" not in r["toolpath"] else round(
        r["toolpath"]["dry_mm"] / max(r["toolpath"]["length_mm"], 1e-9), 4)),
    "upper_traces": g.get("upper_traces"),
    "twist_kept": ((r.get("curvature") or {}).get("twist") or {}).get("kept"),
    "across_kept": ((r.get("curvature") or {}).get("across") or {}).get("kept"),
    "across_traces": g.get("across_traces"),
    "across_spacing_mm": (tp.get("across") or {}).get("spacing_mm"),
    "across_coverage": (tp.get("across") or {}).get("coverage"),
    "coverage": round(r["toolpath"]["coverage"], 4),
    "gcode_lines": g["lines"], "gcode_bytes": g["bytes"], "moves_per_s": g["moves_per_s"],
    "estimated_print_s": g["estimated_print_s"],
    "peak_rss_mb": peak_mb,
    "imports": imports, "stages": stages, "cpu_s": cpu_total, "printable": r.get("printable"),
    "reference_displacement_mm": None if ref is None else round(ref, 3),
    "reference_cpu_s": ref_cpu,
    "fidelity": r.get("fidelity")}))
"""

SHAPE = r"""
import numpy as np
from pipeline.input import shapes
name, out = sys.argv[1], sys.argv[2]
# A third argument: the generated terrain's side (mm), saved as NAME_SIDE.
kw = {"size_mm": float(sys.argv[3])} if len(sys.argv) > 3 else {}
hf = {**shapes.REFERENCE, **shapes.SADDLES, **shapes.TERRAIN}[name](**({"diameter_mm": 175.0} if name in ("dome", "starfish") else kw))
stem = name + ("_" + sys.argv[3].replace(".", "_") if kw else "")
np.save(out + "/" + stem + ".npy", hf.z.astype(np.float32))
# The rough terrain's two closed basins are 10.5 and 7.8 mm deep: filled, as a real
# tile's sidecar fills its own (max_fill_mm), since the sheet cannot form a bowl.
fill = "max_fill_mm: 11\n" if name in shapes.TERRAIN else ""
open(out + "/" + stem + ".yaml", "w").write("pixel_mm: %r\n%s" % (hf.pixel_mm, fill))
print(json.dumps({"path": out + "/" + stem + ".npy"}))
"""

LAYOUT = r"""
import numpy as np
from pipeline.input import heightfield as hfio, shapes
from pipeline.input.sidecar import settings as sidecar_settings
from pipeline.input.validate import validate
from pipeline.input.simplify import simplify
from pipeline.profiles.profile import load_profile
from pipeline.meshing.isoline import build_mesh
from pipeline.meshing.grid import build_grid_mesh
from pipeline.layout.isoline import flatten
from pipeline.layout.free import flatten_free
name, method = sys.argv[1], sys.argv[2]
prof = load_profile("generic-0.5mm")
lim, mp = prof.shrink_limits, prof.mesh
t0 = time.perf_counter()
if name.endswith(".png"):
    hf, side = hfio.load(name, profile=prof)
    hf, _ = hfio.coarsen(hf, prof.validate.working_pixel_mm)
    opts = sidecar_settings(side, prof)
else:
    shape = {**shapes.REFERENCE, **shapes.SADDLES}[name]
    hf = shape(**({"diameter_mm": 175.0} if name in ("dome", "starfish") else {}))
    from pipeline.input.sidecar import Sidecar
    opts = sidecar_settings(Sidecar(), prof)
hf, _ = validate(hf, opts["max_fill_mm"], bed_mm=prof.bed_mm)
hf, _ = simplify(hf, opts["min_prominence_mm"], opts["smooth_mm"])
t1 = time.perf_counter()
out = {"method": method}
if method == "isoline":
    mesh = build_mesh(hf, isoline_step_mm=mp.isoline_step_mm,
                      gradient_spacing_mm=mp.gradient_spacing_mm, l_u_mm=mp.l_u_mm)
    t2 = time.perf_counter()
    flat = flatten(mesh, s_min=lim.s_min, s_max=lim.s_max, iterations=prof.flatten.iterations)
    out.update(invalid_edge_fraction=flat.invalid_edge_fraction,
               stretch_edge_fraction=float(np.mean(flat.sigma < lim.s_min - 1e-3)),
               invalid_area_fraction=flat.invalid_area_fraction,
               stretch_area_fraction=flat.stretch_area_fraction,
               overshrink_area_fraction=flat.overshrink_area_fraction,
               flipped=int(flat.flipped_triangles))
else:
    mesh = build_grid_mesh(hf, 1.0)
    t2 = time.perf_counter()
    flat = flatten_free(mesh, lim.s_min, lim.s_max, iterations=200)
    out.update(invalid_edge_fraction=flat.invalid_edge_fraction,
               invalid_area_fraction=flat.invalid_area_fraction,
               stretch_area_fraction=flat.stretch_area_fraction,
               overshrink_area_fraction=flat.overshrink_area_fraction,
               flipped=int(flat.flipped), iterations=int(flat.iterations))
t3 = time.perf_counter()
out.update(triangles=len(mesh.faces), load_validate_s=round(t1 - t0, 3), mesh_s=round(t2 - t1, 3),
           flatten_s=round(t3 - t2, 3),
           longest_diameter_mm=round(float(np.linalg.norm(np.ptp(mesh.vertices[:, :2], axis=0))), 1),
           peak_rss_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1))
print(json.dumps(out))
"""

FINE_MAP = r"""
import numpy as np
from PIL import Image
out, n = sys.argv[1], int(sys.argv[2])
y, x = np.mgrid[0:n, 0:n]
r = np.hypot(x - n / 2, y - n / 2) / (n / 2)
z = np.where(r < 1, np.sqrt(np.clip(1 - 0.75 * r ** 2, 0, None)) - 0.5, 0.0)
Image.fromarray((z / z.max() * 65535).astype(np.uint16)).save(out + "/fine_map.png")
open(out + "/fine_map.yaml", "w").write("size_mm: 175\nheight_mm: 30\n")
print(json.dumps({"ok": True}))
"""
