"""How close the planned sheet comes to the file as dropped, with the fit smoothing the
whole field (global) or only where the sheet cannot form it (local).

Each model is dropped as heights in mm without a height asked (so the fit runs, as for
a terrain dropped without a sidecar height), at its native size: the real tiles of
``../shared/data/terrain`` at the size and relief of their sidecars, and
``pipeline.input.shapes.rough_terrain()``. Each is planned once per smoothing; printed
as JSON per plan: the report's ``fidelity`` figures (distance to the file as given,
relief reached, right-way curvature where the file curves strongly), the gate's
figures (invalid area, flips, displacement against the planned target), what the fit
removed, and wall and CPU time with the load average.

    python benchmarks/fidelity.py [--models rough,vancouver_island_south,...]
                                  [--modes global,local] [--out results/fidelity.json]

Targets (local against global): distance to the file as given >= 30 % lower, relief
reached >= 80 %, right way where the file curves strongly >= 90 %, invalid area
<= 2 %, no flips.
"""

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.input import heightfield as hfio  # noqa: E402
from pipeline.input import shapes  # noqa: E402
from pipeline.plan import plan_file  # noqa: E402
from pipeline.profiles.profile import load_profile  # noqa: E402

TERRAIN = Path(__file__).resolve().parents[2] / "shared" / "data" / "terrain"
MODELS = ("rough", "vancouver_island_south", "coast_mountains_bc")


def model(name, profile):
    """(z (rows, cols) mm, pixel_mm, max_fill_mm) of a model at its native size."""
    if name == "rough":
        hf = shapes.rough_terrain()
        return hf.z, hf.pixel_mm, 12.0
    hf, sidecar = hfio.load(TERRAIN / (name + ".png"), profile)
    return hf.z, hf.pixel_mm, sidecar.max_fill_mm


def plan_one(name, mode, profile, tmp):
    z, pixel_mm, fill = model(name, profile)
    path = Path(tmp) / (name + ".npy")
    np.save(path, z)
    path.with_suffix(".yaml").write_text("pixel_mm: %r\nmax_fill_mm: %r\n" % (pixel_mm, fill))
    prof = dataclasses.replace(profile, flatten=dataclasses.replace(
        profile.flatten, fit_smoothing=mode))
    t0, c0 = time.perf_counter(), time.process_time()
    plan = plan_file(path, prof)
    r = plan.report
    fit, fid, flat = r.get("fit") or {}, r["fidelity"], r["flatten"]
    return {"model": name, "smoothing": mode, "fidelity": fid,
            "invalid_area_fraction": flat.get("invalid_area_fraction"),
            "flipped": flat.get("flipped_triangles", flat.get("flipped")),
            "mean_displacement_fraction": r["simulation"]["mean_displacement_fraction"],
            "printable": r["printable"], "outside": r["gate"]["outside"],
            "fit": {k: fit.get(k) for k in ("applied_smooth_mm", "applied_scale", "removed_mm",
                                            "removed_p90_mm", "local", "held", "keep")},
            "warnings": [w["code"] for w in r["warnings"]],
            "wall_s": round(time.perf_counter() - t0, 1),
            "cpu_s": round(time.process_time() - c0, 1),
            "loadavg": os.getloadavg()[0]}


def compare(rows):
    """Local against global per model: the distance's drop and the targets met."""
    out = {}
    for name in {r["model"] for r in rows}:
        by = {r["smoothing"]: r for r in rows if r["model"] == name}
        if not {"global", "local"} <= set(by):
            continue
        g, loc = by["global"]["fidelity"], by["local"]["fidelity"]
        drop = 1.0 - loc["mean_mm"] / max(g["mean_mm"], 1e-9)
        out[name] = {"distance_drop": round(drop, 4),
                     "targets": {"distance_drop_30": drop >= 0.30,
                                 "relief_80": loc["relief_reached"] >= 0.80,
                                 "right_way_strong_90": (loc["right_way_strong"] or 0) >= 0.90,
                                 "invalid_area_2": by["local"]["invalid_area_fraction"] <= 0.02,
                                 "no_flips": not by["local"]["flipped"]}}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--modes", default="global,local")
    ap.add_argument("--profile", default="generic-0.5mm")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    profile = load_profile(args.profile)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.models.split(","):
            for mode in args.modes.split(","):
                rows.append(plan_one(name, mode, profile, tmp))
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    result = {"plans": rows, "local_vs_global": compare(rows)}
    text = json.dumps(result, indent=1)
    if args.out:
        Path(args.out).write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
