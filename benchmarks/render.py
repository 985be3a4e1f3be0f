"""Rendering benchmark: prints JSON with seconds per picture at growing sizes.

    .venv/bin/python benchmarks/render.py [--quick]

Meshes are grids over the synthetic starfish (pipeline.input.shapes) triangulated
inside the footprint, so the triangle count is set by the grid spacing. Times
are the best of ``repeat`` runs (wall clock, one process); peak RSS is for the
whole run.
"""

import io
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.input import shapes  # noqa: E402
from pipeline.pictures import hfimage, render  # noqa: E402
from pipeline.geometry import unique_edges  # noqa: E402
from pipeline.plyio import write_ply  # noqa: E402


def grid_mesh(hf):
    z = hf.z
    ok = np.isfinite(z)
    idx = np.full(z.shape, -1)
    idx[ok] = np.arange(ok.sum())
    rr, cc = np.nonzero(ok)
    v = np.column_stack([hf.xy(rr, cc), z[ok]])
    nw, ne, sw, se = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    f = np.concatenate([np.stack([sw, se, ne], -1).reshape(-1, 3),
                        np.stack([sw, ne, nw], -1).reshape(-1, 3)])
    return v, f[(f >= 0).all(1)]


def best(fn, repeat):
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return round(min(ts), 3)


def main(quick=False):
    repeat = 1 if quick else 3
    out = {"preview": [], "stress": [], "ply_write": []}
    # Starfish 175 mm: grid spacing -> triangles (~5k, 20k, 80k, 200k).
    spacings = [1.5, 0.75] if quick else [2.1, 1.05, 0.53, 0.34]
    for pixel_mm in spacings:
        v, f = grid_mesh(shapes.starfish(pixel_mm=pixel_mm))
        sim = v.copy()
        sim[:, 2] *= 0.97
        disp = np.linalg.norm(sim - v, axis=1)
        out["preview"].append({"triangles": len(f), "seconds": best(
            lambda: render.preview_image(v, f, sim, disp, title="bench"), repeat)})
        e = unique_edges(f)
        sigma = np.random.default_rng(0).uniform(-0.02, 0.36, len(e))
        xy = v[:, :2] * 1.05
        out["stress"].append({"triangles": len(f), "edges": len(e), "seconds": best(
            lambda: render.stress_image(xy, e, sigma, 0.0, 0.343, faces=f), repeat)})
        colors = render.colormap(disp, 0, disp.max(), "displacement")
        out["ply_write"].append({"triangles": len(f), "seconds": best(
            lambda: write_ply(io.BytesIO(), sim, f, colors), repeat)})
    # Tool paths: concentric rings 0.48 mm apart, 0.25 mm segments (~200k segments).
    rings = [np.column_stack([r * np.cos(a), r * np.sin(a)]) for r in np.arange(87.5, 1.0, -0.48)
             for a in [np.linspace(0, 2 * np.pi, max(8, int(2 * np.pi * r / 0.25)))]]
    path = np.concatenate(rings)
    out["toolpath"] = {"segments": len(path) - 1, "seconds": best(
        lambda: render.toolpath_image([path], [np.full(len(path) - 1, 0.2)], 0.0, 0.343, 0.48),
        repeat)}
    hf = shapes.three_islands(pixel_mm=0.5)
    out["heightfield"] = {"shape": list(hf.z.shape), "seconds": best(
        lambda: hfimage.heightfield_image(hf.z, [], hf.pixel_mm), repeat)}
    out["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
