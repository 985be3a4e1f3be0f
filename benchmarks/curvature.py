"""What the programmed curvature is worth: one free layout, settled from flat as a thin
shell under different rest curvatures. Prints JSON.

The metric (each triangle's shrink along its print direction) is the layout's; the rows
change the rest dihedral angles, and the plan's rows also the shrink the program adds:

- ``none``: bending toward flat;
- ``bilayer``: the bilayer program (curvature along ``d`` from the 5 mm smoothed field, within
  the shrink range around the layout's shrink);
- ``bilayer_room``: the same where the program adds shrink along ``d`` to make room for the
  thickness difference (``curvature.room_for``; the metric changes there);
- ``bilayer_room_crossed``: that with the layer groups turned apart by the target's twist
  (they shrink by their mean); the plan prints whichever of the last two rests closer
  (``plan_kept_crossing``);
- ``layers_across``: the stack with two layers across ``d`` for the curvature across it and
  the halves along ``d`` turned apart (:mod:`pipeline.layout.laminate`), with its own metric
  and thickness; the plan prints it where it rests closer still (``plan_kept_across``);
- ``along_d``: the target's curvature along ``d`` from the 1 mm smoothed field, no limit;
- ``full_tensor``: the target's whole curvature (1 mm smoothed field) in the layout frame,
  which paths that shrink only along themselves cannot program;
- ``target_angles``: the target mesh's own dihedral angles.

The gap between the plan's rows and ``full_tensor`` is what curvature across the print
direction would bring, and ``layers_across`` how much of it two layers across bring.
Mean displacement as a fraction of the report's longest diameter. Every row starts flat
(the plan tries the twist and the layers across from the sheet the bilayer settled).

    python benchmarks/curvature.py [INPUT ...]   # default: three reference shapes, the real tiles
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
TERRAIN = ROOT.parent / "shared" / "data" / "terrain"


def _inputs(folder):
    """The reference starfish, elongated peak and three islands written as drop files, and
    the real tiles where present."""
    from pipeline.input import shapes
    paths = []
    for name, hf in (("starfish", shapes.starfish(diameter_mm=175.0)),
                     ("elongated_peak", shapes.elongated_peak()),
                     ("three_islands", shapes.three_islands())):
        path = Path(folder) / (name + ".npy")
        np.save(path, hf.z.astype(np.float32))
        path.with_suffix(".yaml").write_text("pixel_mm: %r\n" % hf.pixel_mm)
        paths.append(path)
    return paths + sorted(TERRAIN.glob("*.png"))


def study(path):
    """One input: the plan's figures and the displacement under each rest curvature."""
    from pipeline.layout import curvature
    from pipeline.layout.laminate import across_laminate
    from pipeline.mechanics.constraints import topology
    from pipeline.mechanics.shell import dihedral
    from pipeline.plan import plan_file
    from pipeline.simulation.programmed import BATH_BUMP
    from pipeline.profiles.profile import load_profile
    from pipeline.simulation.shell import (directional_rest, simulate_shell, tensor_rest,
                                          thickness_for)
    prof = load_profile("generic-0.5mm")
    lim = prof.shrink_limits
    p = plan_file(path, prof, method="free", force_fit=path.suffix == ".png")
    mesh, flat = p.mesh, p.flat
    sigma = np.clip(flat.sigma, lim.s_min, lim.s_max)
    rest = directional_rest(flat.xy, mesh.faces, flat.direction, sigma)
    thick = thickness_for(sigma, prof.shrink_curve, prof.layers, prof.thickness_mm.min,
                          prof.thickness_mm.max)
    top = topology(mesh.faces, len(mesh.vertices))
    K = curvature.target_tensor(p.hf, mesh, flat, sigma, smooth_mm=1.0)
    d = flat.direction
    shrink = sigma[:, None, None] * np.einsum("mi,mj->mij", d, d)
    along = np.einsum("mi,mij,mj->m", d, K, d)[:, None, None] * np.einsum("mi,mj->mij", d, d)
    K5 = curvature.target_tensor(p.hf, mesh, flat, sigma)
    roomy = curvature.room_for(K5, d, sigma, thick, lim.s_min, lim.s_max,
                               c=prof.curvature.bilayer_c,
                               added_max=prof.curvature.max_added_shrink)
    thick_roomy = thickness_for(roomy, prof.shrink_curve, prof.layers, prof.thickness_mm.min,
                                prof.thickness_mm.max)
    programs = {name: (curvature.program(K5, mesh.faces, flat.xy, d, s, h, lim.s_min, lim.s_max,
                                         c=prof.curvature.bilayer_c, turn_max_deg=turn), s, h)
                for name, s, h, turn in (
                    ("bilayer", sigma, thick, 0.0),
                    ("bilayer_room", roomy, thick_roomy, 0.0),
                    ("bilayer_room_crossed", roomy, thick_roomy, prof.curvature.turn_max_deg))}
    lam = across_laminate(K5, d, roomy, lambda s: thickness_for(
        s, prof.shrink_curve, 1, prof.thickness_mm.min, prof.thickness_mm.max), prof.layers,
        lim.s_min, lim.s_max, prof.curvature.bilayer_c, turn_max_deg=prof.curvature.turn_max_deg)
    lam_metric = lam.metric(d)
    variants = {
        "none": None, **{name: prog[0].theta_rest for name, prog in programs.items()},
        "layers_across": curvature.rest_angles(flat.xy, mesh.faces, lam_metric,
                                               lam.curvature(d, prof.curvature.bilayer_c), top),
        "along_d": curvature.rest_angles(flat.xy, mesh.faces, shrink, along, top),
        "full_tensor": curvature.rest_angles(flat.xy, mesh.faces, shrink, K, top),
        "target_angles": dihedral(mesh.vertices, top.hinges)}
    diameter = p.report["heightfield"]["longest_diameter_mm"]
    out = {"input": path.name, "fit_scale": (p.fit.applied_scale if p.fit else None),
           "longest_diameter_mm": diameter, "triangles": len(mesh.faces),
           "plan_kept_crossing": p.curvature.crossed,
           "plan_kept_across": p.curvature.laminate is not None}
    for name, theta in variants.items():
        t = time.perf_counter()
        own, h = rest, thick
        if name in programs:
            # The program's own shrink (added room; groups turned apart shrink by their mean).
            prog, s, h = programs[name]
            A, B = prog.group_tensors(d, s)
            own = tensor_rest(flat.xy, mesh.faces, (A + B) / 2)
        if name == "layers_across":
            own, h = tensor_rest(flat.xy, mesh.faces, lam_metric), lam.thickness_mm
        sim = simulate_shell(mesh.vertices, mesh.faces, flat.xy, own, h, theta_rest=theta,
                             pop=BATH_BUMP)
        out[name] = {"mean_displacement_pct": round(100 * sim.mean_displacement_mm / diameter, 3),
                     "iterations": sim.iterations, "converged": sim.converged,
                     "seconds": round(time.perf_counter() - t, 2)}
    return out


def main():
    with tempfile.TemporaryDirectory() as tmp:
        paths = [Path(a) for a in sys.argv[1:]] or _inputs(tmp)
        print(json.dumps([study(p) for p in paths], indent=1))


if __name__ == "__main__":
    main()
