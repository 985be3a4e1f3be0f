"""Input-stage benchmark: prints JSON with seconds for fill, validate and simplify.

    .venv/bin/python benchmarks/validate.py [--quick]

Synthetic fields are a dome with Gaussian-filtered noise (hundreds of pits and
peaks) on n x n grids; real terrain is ../shared/data/terrain with its
sidecars and the generic-0.5mm profile (skipped when absent). Times are the best
of ``repeat`` runs (wall clock, one process); peak RSS is for the whole run.
"""

import json
import resource
import sys
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.geometry import HeightField  # noqa: E402
from pipeline.input.heightfield import load  # noqa: E402
from pipeline.profiles.profile import load_profile  # noqa: E402
from pipeline.input.simplify import simplify  # noqa: E402
from pipeline.input.validate import fill_depressions, validate  # noqa: E402


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def noisy_dome(n, pixel_mm=0.25):
    rng = np.random.default_rng(1)
    y, x = np.mgrid[0:n, 0:n]
    r = np.hypot(x - n / 2, y - n / 2) / (n / 2 - 2)
    z = 30 * np.cos(np.minimum(r, 1) * np.pi / 2) + gaussian_filter(rng.random((n, n)), 3) * 40
    z[r > 1] = np.nan
    return HeightField(z, pixel_mm, source="noisy_dome_%d" % n)


def main():
    quick = "--quick" in sys.argv
    repeat = 1 if quick else 3
    out = {"synthetic": [], "terrain": []}
    for n in ([200, 450] if quick else [200, 450, 700, 1000]):
        hf = noisy_dome(n)
        t_fill, (_, info) = best(lambda: fill_depressions(hf.z), repeat)
        t_val, (v, rep) = best(lambda: validate(hf, 100.0), repeat)
        t_simp, (_, srep) = best(lambda: simplify(v, 2.0, 1.0), repeat)
        out["synthetic"].append({
            "shape": [n, n], "cells": int(np.isfinite(hf.z).sum()), "fill_s": round(t_fill, 4),
            "validate_s": round(t_val, 4), "simplify_s": round(t_simp, 4),
            "filled_pits": rep["filled_pits"], "peaks_before": srep["peaks_before"],
            "peaks_after": srep["peaks_after"]})
    terrain = ROOT.parent / "shared" / "data" / "terrain"
    if terrain.is_dir():
        profile = load_profile("generic-0.5mm")
        for png in sorted(terrain.glob("*.png")):
            t_load, (hf, sc) = best(lambda: load(png, profile), repeat)
            t_val, (v, rep) = best(lambda: validate(hf, sc.max_fill_mm), repeat)
            t_simp, (_, srep) = best(lambda: simplify(v, profile.mesh.min_prominence_mm,
                                                      profile.mesh.smooth_mm), repeat)
            out["terrain"].append({
                "input": png.name, "load_s": round(t_load, 4), "validate_s": round(t_val, 4),
                "simplify_s": round(t_simp, 4), "filled_pits": rep["filled_pits"],
                "deepest_fill_mm": round(rep["deepest_fill_mm"], 3),
                "peaks_before": srep["peaks_before"], "peaks_after": srep["peaks_after"],
                "removed_peaks": srep["removed_count"],
                "max_change_mm": round(srep["max_change_mm"], 3)})
    out["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
