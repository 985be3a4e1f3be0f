"""What a G-code file will do before it is written: print time, filament, the report's
``gcode`` figures and the viewer header (Cura's and PrusaSlicer's comment lines).

The time estimate is :mod:`pipeline.gcode.printtime`'s trapezoid model, timed on the
polyline before arc fitting (arcs change it negligibly).
"""

from dataclasses import dataclass

import numpy as np

from pipeline import __version__
from pipeline.gcode.numfmt import fmt
from pipeline.gcode.printtime import (MAX_Z_SPEED_MM_S, estimate_time_text, polyline_time_s,
                                      trapezoid_s)


@dataclass(frozen=True)
class Timing:
    """Estimated times (s) and lengths (mm) of a whole file."""

    total_s: float
    path_length_mm: float
    z_speed_mm_s: float


def estimate(q, starts, mv, text, settings, layers=None):
    """Print time of the layers ``(first, last)`` (1-based, default all) that print one
    set of moves: extrusion, travel between traces, retractions and hops.

    q : (n, 2) int, um, one layer's points; starts : (t+1,) int, trace i owns
    ``q[starts[i]:starts[i+1]]``; mv : moves of one layer; text : :class:`MoveText`.
    """
    first, last = layers or (1, settings.layers)
    count = last - first + 1
    acc = settings.acceleration_mm_s2
    jd = settings.junction_deviation_mm
    t_rest, length_mm = polyline_time_s(q / 1000.0, starts, settings.print_mm_s, acc, jd)
    t_first = (polyline_time_s(q / 1000.0, starts, settings.first_layer_mm_s, acc, jd)[0]
               if first == 1 else t_rest)
    travel_from = np.concatenate([[[0, 0]], mv["end"][text.trace_ends[:-1] - 1]]) / 1000.0
    travel_to = mv["start"] / 1000.0
    travel_len = np.hypot(*(travel_to - travel_from).T)
    travel_rest = travel_len.copy()
    # Later layers start with the hop from the last layer's end, not from the origin.
    travel_rest[0] = np.hypot(*(travel_to[0] - mv["end"][-1] / 1000.0))
    v_tr = settings.travel_mm_s
    t_travel = (trapezoid_s(travel_len if first == 1 else travel_rest, 0.0, 0.0, v_tr, acc).sum()
                + (count - 1) * trapezoid_s(travel_rest, 0.0, 0.0, v_tr, acc).sum())
    z_speed = min(v_tr, MAX_Z_SPEED_MM_S)
    t_retract = 2 * settings.retract_mm / settings.retract_mm_s if settings.retract_mm > 0 else 0
    t_hop = 2 * settings.z_hop_mm / z_speed
    n_traces = len(starts) - 1
    t_total = (t_first + (count - 1) * t_rest + t_travel
               + n_traces * count * (t_retract + t_hop))
    return Timing(float(t_total), float(length_mm), float(z_speed))


def summary(parts, settings, clamped_segments):
    """The report's ``gcode`` figures known before writing (``lines`` and ``bytes`` are
    filled in by the writer). parts : one (group, q, starts, th_mm, timing) per
    :class:`pipeline.gcode.layers.Group`, th_mm (s, K) each segment's thickness; where
    layer groups print their own paths, counts add up over the groups and
    ``moves_per_s`` is the busiest group's."""
    layers = settings.layers
    th_all = np.concatenate([p[3].ravel() for p in parts])
    filament = sum(p[0].text.filament_mm for p in parts)
    lower, timing_lower = parts[0], parts[0][4]
    stats = {
        "lines": 0, "bytes": 0, "layers": layers,
        "thickness_mm": {"min": float(th_all.min()), "max": float(th_all.max())},
        "clamped_segments": int(clamped_segments),
        "filament_mm": round(float(filament), 3),
        "filament_g": round(float(filament_g(filament, settings)), 3),
        "estimated_print_s": round(sum(p[4].total_s for p in parts), 1), "bed_fits": True,
        "travel_moves": sum((len(p[2]) - 1) * p[0].layers for p in parts),
        "traces": len(lower[2]) - 1,
        "segments": sum(len(p[1]) - (len(p[2]) - 1) for p in parts),
        "extrusion_moves": sum(len(p[0].mv["len"]) * p[0].layers for p in parts),
        "path_length_mm": round(timing_lower.path_length_mm, 3),
        "moves_per_s": round(max(len(p[0].mv["len"]) / max(p[4].path_length_mm
                                                            / settings.print_mm_s, 1e-9)
                                 for p in parts), 1),
    }
    if len(parts) > 1:
        stats["upper_traces"] = len(parts[1][2]) - 1
    if settings.arc_tolerance_mm > 0:
        stats["arcs"] = sum(int((p[0].mv["kind"] != 1).sum()) * p[0].layers for p in parts)
    return stats


def filament_g(filament_mm, settings):
    return filament_mm * settings.filament_area_mm2 / 1000.0 * settings.filament_density_g_cm3


def header_lines(parts, settings, name, extra=()):
    """The file's opening comment lines (viewer furniture and a human summary).

    parts : as :func:`summary`'s; th_mm (segments, K) each segment's thickness, for all
    layers (K = 1) or each."""
    layers = settings.layers
    stacks = [p[3][:, 0] * layers if p[3].shape[1] == 1 else p[3].sum(axis=1) for p in parts]
    th_all = np.concatenate([p[3].ravel() for p in parts])
    # Arcs bulge at most the arc tolerance past their end points: ignored here.
    xy_all = np.concatenate([np.concatenate([p[0].mv["end"], p[0].mv["start"]])
                             for p in parts]) / 1000.0
    lo_xy, hi_xy = xy_all.min(axis=0), xy_all.max(axis=0)
    f_mm = sum(p[0].text.filament_mm for p in parts)
    total_s = sum(p[4].total_s for p in parts)
    area = settings.filament_area_mm2
    traces = " / ".join("%d" % len(p[0].text.trace_ends) for p in parts)
    return [
        ";FLAVOR:Marlin",
        ";TIME:%d" % round(total_s),
        ";Filament used: %sm" % fmt(f_mm / 1000.0, 5),
        ";LAYER_COUNT:%d" % layers,
        ";MINX:%s" % fmt(lo_xy[0]), ";MINY:%s" % fmt(lo_xy[1]),
        ";MINZ:%s" % fmt(th_all.min()),
        ";MAXX:%s" % fmt(hi_xy[0]), ";MAXY:%s" % fmt(hi_xy[1]),
        ";MAXZ:%s" % fmt(max(st.max() for st in stacks)),
        ";generated by hostd %s" % __version__,
        "; job: %s" % one_line(name),
        "; profile: %s" % one_line(settings.profile_name),
        "; layers: %d, traces per layer: %s, thickness %s..%s mm, E %s" % (
            layers, traces + (" (lower / upper layer group)" if len(parts) > 1 else ""),
            fmt(th_all.min()), fmt(th_all.max()),
            "relative" if settings.relative_e else "absolute"),
        "; filament used [mm] = %.2f" % f_mm,
        "; filament used [cm3] = %.3f" % (f_mm * area / 1000.0),
        "; filament used [g] = %.3f" % filament_g(f_mm, settings),
        "; estimated printing time (normal mode) = %s" % estimate_time_text(total_s),
    ] + ["; " + one_line(h) for h in extra]


def one_line(text):
    """``text`` with every run of whitespace (newlines too) as one space."""
    return " ".join(str(text).split())
