"""Flattening and forward-simulation speed on one core; prints JSON.

    python benchmarks/flatten.py            # 5k, 20k, 80k, 200k triangles
    python benchmarks/flatten.py 20000      # one size

Meshes are polar meshes of the default 120 mm dome (isoline rings, Delaunay
bridges; tests/meshes.py), refined to the requested triangle count. Each size
runs in its own process so that its peak resident memory (ru_maxrss) is its own.
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, and no BLAS threads spinning in SuperLU's solves

import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

SIZES = (5000, 20000, 80000, 200000)


def cap_mesh(triangles):
    """Dome mesh with about ``triangles`` faces (rings 4x the printing edge apart)."""
    from meshes import spherical_cap
    # faces ~ 2 * area / (l_u * ring) with ring = 4 l_u; cap area ~ 1.26e4 mm^2
    l_u = (2 * 1.26e4 / (4.0 * triangles)) ** 0.5
    mesh, _ = spherical_cap(84.5, 25.0, ring_arc_mm=4.0 * l_u, l_u=l_u)
    return mesh, l_u


def run_one(triangles, simulate_too=True):
    from pipeline.layout.isoline import flatten
    from pipeline.simulation.forward import simulate
    mesh, l_u = cap_mesh(triangles)
    t = time.perf_counter()
    flat = flatten(mesh, iterations=50)
    t_flat = time.perf_counter() - t
    out = {"triangles": int(len(mesh.faces)), "vertices": int(len(mesh.vertices)),
           "l_u_mm": round(l_u, 3), "flatten_s": round(t_flat, 3),
           "flatten_phases_s": {k: round(v, 3) for k, v in flat.timing_s.items()},
           "relocation_iterations": flat.iterations,
           "planar_iterations": len(flat.energy_history) - flat.iterations,
           "invalid_edge_fraction": round(flat.invalid_edge_fraction, 4),
           "flipped_triangles": flat.flipped_triangles}
    if simulate_too:
        t = time.perf_counter()
        sim = simulate(mesh, flat)
        out["simulate_s"] = round(time.perf_counter() - t, 3)
        out["simulate_iterations"] = sim.iterations
        out["simulate_mean_displacement_mm"] = round(sim.mean_displacement_mm, 3)
    out["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    return out


def main(argv):
    if len(argv) == 2 and argv[1].startswith("--one="):
        print(json.dumps(run_one(int(argv[1][6:]))))
        return
    sizes = [int(a) for a in argv[1:]] or SIZES
    results = []
    for n in sizes:
        proc = subprocess.run([sys.executable, __file__, "--one=%d" % n],
                              capture_output=True, text=True, check=True)
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        print(json.dumps(results[-1]), file=sys.stderr)
    print(json.dumps({"benchmark": "flatten", "one_core": True,
                      "targets_s": {"20k": 1.5, "200k": 20.0}, "results": results}, indent=1))


if __name__ == "__main__":
    main(sys.argv)
