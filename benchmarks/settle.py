"""The free sheet's check, coarse to fine, beside the full settle of the same program.
Prints JSON.

Each model is planned twice in a fresh child process pinned to one core (BLAS threads
1), the whole plan as ``hostd plan`` runs it with the fit (no height taken from the
sidecar): once as shipped (:func:`pipeline.simulation.staged.simulate_free`: the trials
on the coarse sheet, the program chosen settled once on the plan's mesh from the coarse
rest) and once with the same program settled on the plan's mesh from the bath
(``reference=True``, :func:`pipeline.simulation.staged.reference_settle`). Per model:
coarse and fine iterations, CPU seconds per fine iteration, the simulate stage's CPU
seconds, the mean displacement both ways and the printable verdict both ways. With
``--trials`` a third plan settles as the plan did before (every trial on the plan's
mesh, :func:`pipeline.simulation.programmed.simulate_free`): its settles one by one.
Targets are reported next to the measurements; nothing here asserts them. The machine's
load is given with each model: CPU seconds are the figures to read on a shared host.

    python benchmarks/settle.py                      # every model
    python benchmarks/settle.py --only dome --trials
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TERRAIN = ROOT.parent / "shared" / "data" / "terrain"
ONE_CORE = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
TARGETS = {"simulate_cpu_s": 3.0, "displacement_gap": 0.10, "displacement_gap_mm": 0.05,
           "peak_rss_mb": 400}
# The real tiles at 175 mm: their sidecars' size times 175 over their longest diameter.
TILES = {"vancouver_island_south": 159.0, "coast_mountains_bc": 146.4}
MODELS = ("dome", "three_islands", "rough_terrain") + tuple(TILES)

PLAN = r"""
import functools, json, os, resource, sys, time
os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
from pipeline import plan as planner
from pipeline.layout import free_method
from pipeline.profiles.profile import load_profile
from pipeline.simulation import programmed, staged
path, mode = sys.argv[1], sys.argv[2]
settle = {"fast": staged.simulate_free,
          "reference": functools.partial(staged.simulate_free, reference=True),
          "trials": programmed.simulate_free}[mode]
seen, settles = {}, []
shell = programmed.simulate_shell


def timed_shell(vertices, *args, **kw):
    c = time.process_time()
    sim = shell(vertices, *args, **kw)
    settles.append({"vertices": len(vertices), "iterations": sim.iterations,
                    "cpu_s": round(time.process_time() - c, 3),
                    "from": "bath" if kw.get("start") is None else "shape"})
    return sim


def timed(*args, **kw):
    c = time.process_time()
    out = settle(*args, **kw)
    seen["cpu_s"] = time.process_time() - c
    seen["sim"] = out[1]
    return out
programmed.simulate_shell = timed_shell
free_method.simulate_free = timed
plan = planner.plan_file(path, load_profile("generic-0.5mm"), force_fit=True, method="free")
sim, r = seen["sim"], plan.report
fine = [s for s in settles if s["vertices"] == len(plan.mesh.vertices)]
fine_it = sum(s["iterations"] for s in fine)
print(json.dumps({
    "triangles": r["mesh"]["triangles"], "simulate_cpu_s": round(seen["cpu_s"], 3),
    "simulate_wall_s": r["timing_s"]["simulate"],
    "coarse_iterations": int(sim.coarse_iterations),
    "fine_iterations": fine_it,
    "fine_s_per_iteration": round(sum(s["cpu_s"] for s in fine) / max(fine_it, 1), 4),
    "settles": settles, "timing_s": sim.timing_s,
    "mean_displacement_mm": round(sim.mean_displacement_mm, 4),
    "converged": bool(sim.converged), "printable": bool(plan.printable),
    "choice": programmed.choice_of(plan.curvature),
    "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    "load": os.getloadavg()[0]}))
"""


def _model(name, folder):
    """The input file of ``name``: a real tile at 175 mm or a generated shape."""
    import shutil

    import numpy as np
    import yaml
    folder = Path(folder)
    if name in TILES:
        png = TERRAIN / (name + ".png")
        side = yaml.safe_load(png.with_suffix(".yaml").read_text())
        side["size_mm"] = round(float(side["size_mm"]) * 175.0 / TILES[name], 2)
        shutil.copy(png, folder / png.name)
        (folder / png.name).with_suffix(".yaml").write_text(yaml.safe_dump(side))
        return folder / png.name
    sys.path.insert(0, str(ROOT))
    from pipeline.input import shapes
    hf = getattr(shapes, name)(**({"diameter_mm": 175.0} if name == "dome" else {}))
    np.save(folder / (name + ".npy"), hf.z.astype(np.float32))
    # The rough terrain's valleys close deeper than the default fill.
    fill = "max_fill_mm: 11\n" if name == "rough_terrain" else ""
    (folder / (name + ".yaml")).write_text("pixel_mm: %r\n%s" % (hf.pixel_mm, fill))
    return folder / (name + ".npy")


def _child(path, mode):
    env = dict(os.environ, **ONE_CORE)
    out = subprocess.run([sys.executable, "-c", PLAN, str(path), mode], env=env, cwd=ROOT,
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr else "failed"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench(names=MODELS, trials=False):
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            if name in TILES and not TERRAIN.is_dir():
                out[name] = {"skipped": "../shared/data/terrain not present"}
                continue
            path = _model(name, tmp)
            fast, ref = _child(path, "fast"), _child(path, "reference")
            row = {"fast": fast, "reference": ref}
            if "error" not in fast and "error" not in ref:
                gap = abs(fast["mean_displacement_mm"] - ref["mean_displacement_mm"])
                row["displacement_gap_mm"] = round(gap, 4)
                row["displacement_gap"] = round(gap / max(ref["mean_displacement_mm"], 1e-9), 4)
                row["same_verdict"] = fast["printable"] == ref["printable"]
                row["same_program"] = fast["choice"] == ref["choice"]
            if trials:
                row["trials"] = _child(path, "trials")
            out[name] = row
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=MODELS, action="append")
    ap.add_argument("--trials", action="store_true",
                    help="also plan with every trial settled on the plan's mesh")
    args = ap.parse_args()
    print(json.dumps({"targets": TARGETS, "host": os.uname().machine,
                      "models": bench(args.only or MODELS, args.trials)}, indent=1))


if __name__ == "__main__":
    main()
