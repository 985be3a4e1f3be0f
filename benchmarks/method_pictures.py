"""The pictures of docs/method.md, from real plans of small shapes; prints JSON of their figures.

    .venv/bin/python benchmarks/method_pictures.py [--out docs/method] [--cache DIR]

Each picture is drawn from what :func:`pipeline.plan.plan_file` returned for a small shape
(generic-0.5mm profile): a saddle with both layout methods, a starfish and a rough terrain
with the free one. Nothing is drawn by hand: the colours are the plans' own arrays. With
``--cache`` the plans are kept as pickles and reused, to redraw without planning again.
"""

import argparse
import dataclasses
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.input import shapes  # noqa: E402
from pipeline.pictures import figure, hfimage, render  # noqa: E402
from pipeline.pictures.raster import rasterize_triangles  # noqa: E402
from pipeline.plan import plan_file  # noqa: E402
from pipeline.profiles.profile import load_profile  # noqa: E402

PANEL_PX = 900
# name: (shape, layout method, simulation, sidecar keys): small enough to plan in seconds
# each. Both saddles are planned as given (no fit), so the two methods meet one target.
RUNS = {
    "saddle_isoline": (lambda: shapes.saddle(60.0, 45.0, 16.0), "isoline", "shell", {}),
    "saddle_free": (lambda: shapes.saddle(60.0, 45.0, 16.0), "free", None, {"fit": "off"}),
    "starfish_free": (lambda: shapes.starfish(80.0, 15.0), "free", None, {}),
    "rough_free": (lambda: shapes.rough_terrain(60.0, 12.0), "free", None, {}),
}


def plan(name, folder, profile):
    """Plan one of :data:`RUNS` from a .npy and its sidecar, as a dropped file is planned."""
    make, method, simulation, sidecar = RUNS[name]
    hf = make()
    path = Path(folder) / (name + ".npy")
    np.save(path, hf.z)
    path.with_suffix(".yaml").write_text(yaml.safe_dump({"pixel_mm": float(hf.pixel_mm), **sidecar}))
    if simulation:
        profile = dataclasses.replace(profile, flatten=dataclasses.replace(
            profile.flatten, simulation=simulation))
    cpu, wall = time.process_time(), time.perf_counter()
    result = plan_file(path, profile, method=method)
    return result, {"cpu_s": round(time.process_time() - cpu, 1),
                    "wall_s": round(time.perf_counter() - wall, 1)}


def face_image(xy, faces, values, vmin, vmax, title, label, unit="", scale=1.0, cmap="shrink"):
    """The flat sheet with each triangle coloured by ``values`` ((m,)), a colour bar and a
    scale bar: a PIL image."""
    xy = np.asarray(xy, float)[:, :2]
    lo, hi = xy.min(0), xy.max(0)
    s = (PANEL_PX - 24) / float((hi - lo).max())
    w, h = (np.ceil((hi - lo) * s) + 24).astype(int)
    p = np.column_stack([(xy[:, 0] - lo[0]) * s + 12, (hi[1] - xy[:, 1]) * s + 12])
    fid = rasterize_triangles(p, np.zeros(len(p)), np.asarray(faces, np.int64), (h, w))
    canvas = np.full((h, w, 3), figure.WHITE)
    colors = figure.colormap(values, vmin, vmax, cmap).astype(float)
    canvas[fid >= 0] = colors[fid[fid >= 0]]
    q = np.percentile(values, [5, 50, 95])
    sub = "p05 / p50 / p95: %s / %s / %s%s" % tuple(
        [figure.fmt_number(v * scale, 0.01) for v in q] + [unit])
    fig, bxy, (lx, ly), (fx, fy), fs = figure.framed(figure.to_image(canvas), title, sub)
    figure.colorbar(fig, lx, ly, 26, 300, cmap, vmin, vmax, label, scale=scale, unit=unit, fs=fs)
    figure.scale_bar(fig, bxy[0] + 12, fy + fs, s, min(0.3 * w, 600), fs)
    return fig


def symmetric(v, q=98):
    return max(float(np.percentile(np.abs(v), q)), 1e-6)


def layout_picture(plans, lim):
    """The saddle laid out by each method, shrink per printing edge (isoline) or triangle."""
    iso, free = plans["saddle_isoline"], plans["saddle_free"]
    a = render.stress_image(iso.flat.xy, iso.mesh.printing_edges, iso.flat.sigma, lim.s_min,
                            lim.s_max, faces=iso.mesh.faces, max_px=PANEL_PX,
                            title="isoline: shrink along the isolines")
    b = render.direction_image(free.flat.xy, free.mesh.faces, free.flat.direction,
                               free.flat.sigma, lim.s_min, lim.s_max, max_px=PANEL_PX,
                               title="free: a print direction per triangle")
    return render.montage([a, b], ["isoline (the paper's)", "free (the default)"],
                          title="A 60 mm saddle laid out flat by each method")


def direction_picture(plans, lim):
    p = plans["starfish_free"]
    return render.direction_image(p.flat.xy, p.mesh.faces, p.flat.direction, p.flat.sigma,
                                 lim.s_min, lim.s_max, max_px=PANEL_PX + 300,
                                 title="80 mm starfish, free layout: print direction and shrink")


def curvature_picture(plans):
    p = plans["starfish_free"]
    c, xy, faces = p.curvature, p.flat.xy, p.mesh.faces
    d = c.delta_sigma
    panels = [face_image(xy, faces, d, -symmetric(d), symmetric(d), "bilayer",
                         "lower - upper shrink (%)", scale=100)]
    labels = ["bilayer: lower layers shrink more where the sheet curls up"]
    if c.crossed:
        turn = np.degrees(c.turn_bottom - c.turn_top)
        panels.append(face_image(xy, faces, turn, -symmetric(turn), symmetric(turn), "twist",
                                 "lower - upper direction (deg)"))
        labels.append("twist: the two halves turned apart")
    lam = c.laminate
    if lam is not None:
        low, up = lam.layer_sigma[:, lam.across].T[[0, -1]]
        diff = low - up
        panels.append(face_image(xy, faces, diff, -symmetric(diff), symmetric(diff),
                                 "layers across", "2nd - 2nd last layer shrink (%)", scale=100))
        labels.append("layers across: curl across the paths")
    return render.montage(panels, labels, height_px=460,
                          title="80 mm starfish: the curvature programmed through the layers")


def fit_picture(plans, profile):
    p = plans["rough_free"]
    step = profile.mesh.isoline_step_mm
    given = hfimage.heightfield_image(p.validated.z, pixel_mm=p.validated.pixel_mm,
                                      title="as given", isoline_step_mm=step)
    fitted = hfimage.heightfield_image(p.hf.z, pixel_mm=p.hf.pixel_mm, isoline_step_mm=step,
                                       title="smoothed %g mm by the fit" % p.fit.applied_smooth_mm)
    return render.montage([given, fitted], ["as given", "as fitted and planned"],
                          title="60 mm rough terrain: the fit smooths what the layers cannot curl")


def stripes_picture(plans, lim, pw):
    p = plans["starfish_free"]
    tp = p.toolpaths
    travel = [(a[-1], b[0]) for a, b in zip(tp.traces[:-1], tp.traces[1:])]
    whole = render.toolpath_image(tp.traces, tp.sigma, lim.s_min, lim.s_max, pw,
                                  travel=np.array(travel) if travel else None, dry=tp.dry,
                                  max_px=PANEL_PX + 300,
                                  title="80 mm starfish: lower layers' stripes, joined")
    # A close look at the middle (its singular point, forks and hops), drawn finer.
    fine = render.toolpath_image(tp.traces, tp.sigma, lim.s_min, lim.s_max, pw, dry=tp.dry,
                                 px_per_mm=40.0, max_px=4000)
    s, (ox, oy) = fine.info["px_per_mm"], fine.info["origin_px"]
    cx, cy = np.concatenate(tp.traces).mean(axis=0)
    half = 12.0 * s
    crop = fine.crop((int(ox + s * cx - half), int(oy - s * cy - half),
                      int(ox + s * cx + half), int(oy - s * cy + half)))
    return render.montage([whole, crop], ["one trace a layer", "24 mm round the middle: hops joining the stripes' ends (dark: moved dry)"],
                          height_px=620)


def shell_picture(plans):
    out = []
    for name in ("saddle_isoline", "saddle_free"):
        p = plans[name]
        sim = p.sim
        faces = p.mesh.faces if sim.faces is None else sim.faces
        target = p.mesh.vertices if sim.target is None else sim.target
        out.append(render.preview_image(
            target, faces, sim.vertices, sim.displacement_mm, vmax_mm=4.0,
            title="%s method, thin shell: %.2f mm mean" % (
                p.report["flatten"]["method"], sim.mean_displacement_mm),
            inverted_faces=p.inverted["faces"] if p.inverted else None))
    return render.montage(out, ["isoline layout", "free layout"], height_px=420, columns=1,
                          title="The 60 mm saddle's sheets settled as thin shells (target | settled)")


def figures(name, p, cost):
    """The figures of one run the text quotes beside its picture."""
    r = p.report
    out = dict(cost, diameter_mm=r["heightfield"]["longest_diameter_mm"],
               triangles=len(p.mesh.faces), method=r["flatten"]["method"],
               mean_displacement_mm=round(float(p.sim.mean_displacement_mm), 3),
               traces=r["toolpath"]["traces"], coverage=round(r["toolpath"]["coverage"], 3))
    for k in ("invalid_area_fraction", "invalid_edge_fraction"):
        if k in r["flatten"]:
            out[k] = round(float(r["flatten"][k]), 3)
    for k in ("hop_mm", "dry_mm", "ring_bridges", "fork_triangles"):
        if k in r["toolpath"]:
            out[k] = round(float(r["toolpath"][k]), 1)
    if p.fit is not None:
        out["fit"] = {"smooth_mm": p.fit.applied_smooth_mm, "scale": p.fit.applied_scale,
                      "removed_mm": p.fit.removed_mm and round(p.fit.removed_mm, 2)}
    if p.curvature is not None:
        out["curvature"] = {k: v for k, v in p.curvature.report().items()
                            if k in ("twist", "across", "added_shrink", "crossing_deg")}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "method"))
    ap.add_argument("--cache", help="keep the plans here as pickles and reuse them")
    args = ap.parse_args()
    profile = load_profile("generic-0.5mm")
    lim = profile.shrink_limits
    plans, info = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in RUNS:
            cached = Path(args.cache, name + ".pickle") if args.cache else None
            if cached and cached.exists():
                plans[name], cost = pickle.loads(cached.read_bytes())
            else:
                plans[name], cost = plan(name, tmp, profile)
                if cached:
                    cached.parent.mkdir(parents=True, exist_ok=True)
                    cached.write_bytes(pickle.dumps((plans[name], cost)))
            info[name] = figures(name, plans[name], cost)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pictures = {"layout": layout_picture(plans, lim), "direction": direction_picture(plans, lim),
                "curvature": curvature_picture(plans), "fit": fit_picture(plans, profile),
                "stripes": stripes_picture(plans, lim, profile.path_width_mm),
                "shell": shell_picture(plans)}
    for name, image in pictures.items():
        # A palette of 256 colours keeps the pictures a fifth of their size in the repository (3.4 -> 0.8 MB).
        image.quantize(256, method=2).save(out / (name + ".png"), optimize=True)
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    print(json.dumps({"runs": info, "pictures": sorted(pictures), "profile": "generic-0.5mm",
                      "commit": commit, "load_average": list(os.getloadavg())},
                     indent=1, default=str))


if __name__ == "__main__":
    main()
