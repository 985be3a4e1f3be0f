"""The plan's report: the dict of what each stage made, which other tools read (the
daemon, the status page, the benchmarks; add keys freely, never rename).

``of_plan`` builds it from a :class:`pipeline.plan.Plan` once its sheet is simulated and
its paths are drawn; the plan adds ``fidelity``, ``gate`` and the looks after it.
"""

import numpy as np

from pipeline import __version__
from pipeline.simulation import inverted


def of_plan(path, profile, p, vrep, srep, timing):
    """The report of plan ``p`` of input ``path`` (a Path): lengths in mm, times in s.

    vrep, srep : the validation's and the simplification's reports; timing : stage ->
    seconds so far."""
    hf, mesh, flat, sim = p.hf, p.mesh, p.flat, p.sim
    extent = np.ptp(flat.xy, axis=0)
    relief = float(np.nanmax(hf.z) - np.nanmin(hf.z))
    return {
        "input": path.name,
        "profile": profile.name,
        "pipeline_version": __version__,
        "heightfield": {
            "shape": [int(s) for s in p.input_hf.z.shape],
            "pixel_mm": float(p.input_hf.pixel_mm),
            "working_shape": [int(s) for s in hf.z.shape],
            "working_pixel_mm": float(hf.pixel_mm),
            "longest_diameter_mm": float(vrep["longest_diameter_mm"]),
            "max_height_mm": float(vrep["max_height_mm"]),
            "filled_pits": int(vrep["filled_pits"]),
            "filled_volume_mm3": float(vrep["filled_volume_mm3"]),
            "deepest_fill_mm": float(vrep.get("deepest_fill_mm", 0.0)),
            "has_color": hf.color is not None,
            **({"up": p.input_hf.up} if p.input_hf.up else {}),
            "simplified": {"peaks_before": int(srep.get("peaks_before", 0)),
                           "peaks_after": int(srep.get("peaks_after", 0)),
                           "removed_peaks": int(srep.get("removed_count",
                                                         len(srep.get("removed_peaks", [])))),
                           "max_change_mm": float(srep.get("max_change_mm", 0.0))},
        },
        "mesh": {
            "vertices": int(len(mesh.vertices)),
            "triangles": int(len(mesh.faces)),
            "printing_edges": int(len(mesh.printing_edges)),
            "bridge_edges": int(len(mesh.bridge_edges)),
            "isolines": int(mesh.info.get("isolines", 0)),
            "open_isolines": int(mesh.info.get("open_isolines", 0)),
            "saddles": int(mesh.info.get("saddles", 0)),
            "peaks": int(mesh.info.get("peaks", 0)),
        },
        "flatten": dict(flat.report(), flat_size_mm=[float(extent[0]), float(extent[1])],
                        fold_area_fraction=p.fold_fraction),
        "simulation": dict(sim.report(), mean_displacement_fraction=float(
            sim.mean_displacement_mm / max(vrep["longest_diameter_mm"], 1e-9)),
            relief_mm=relief,
            mean_displacement_of_relief=float(sim.mean_displacement_mm / max(relief, 1e-9)),
            **({"inverted": inverted.report(p.inverted)} if p.inverted else {})),
        "toolpath": _json_ready(dict(p.toolpaths.info, **{
            key: paths.info for key, paths in (("upper", p.upper_toolpaths),
                                               ("across", p.across_toolpaths))
            if paths is not None})),
        "timing_s": {k: round(float(v), 4) for k, v in timing.items()},
        **({"curvature": _curvature_report(p.curvature, profile.curvature, p.reach)}
           if p.curvature is not None else {}),
        **({"fit": p.fit.report()} if p.fit is not None else {}),
        "printable": p.printable,
        "warnings": list(p.problems),
    }


def _json_ready(d):
    if isinstance(d, dict):
        return {k: _json_ready(v) for k, v in d.items()}
    if isinstance(d, (np.floating, float)):
        return float(d)
    if isinstance(d, (np.integer, int)) and not isinstance(d, bool):
        return int(d)
    return d


def _curvature_report(program, cp, reach_report=None):
    """The report's ``curvature``: the program's, with the constants it was made with and
    how far the target bends against the most the stack can curl (``reach``)."""
    out = dict(program.report(), bilayer_c=cp.bilayer_c, bilayer_c_status=cp.status,
               **({"reach": reach_report} if reach_report is not None else {}))
    if "across" in out:
        out["across"] = dict(out["across"], c_across=cp.across_constant,
                             across_status=cp.across_status)
    return out
