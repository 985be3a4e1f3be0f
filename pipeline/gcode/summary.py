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


def estimate(q, starts, mv, text, settings, layers=None, flow=None):
    """Print time of the layers ``(first, last)`` (1-based, default all) that print one
    set of moves: extrusion, dry moves, travel between traces, retractions and hops.

    q : (n, 2) int, um, one layer's points; starts : (t+1,) int, trace i owns
    ``q[starts[i]:starts[i+1]]``; mv : moves of one layer; text : :class:`MoveText`;
    flow : (s,) per segment of the traces, 0 where it moves dry (default all extruded).
    """
    first, last = layers or (1, settings.layers)
    count = last - first + 1
    acc = settings.acceleration_mm_s2
    jd = settings.junction_deviation_mm
    t_rest, length_mm = polyline_time_s(q / 1000.0, starts, _speeds(settings.print_mm_s,
                                                                     flow, settings), acc, jd)
    t_first = (polyline_time_s(q / 1000.0, starts, _speeds(settings.first_layer_mm_s, flow,
                                                            settings), acc, jd)[0]
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


def _speeds(print_mm_s, flow, settings):
    """Feed rate per segment, mm/s: dry moves run at the travel speed, as a slicer's
    combing moves over infill do."""
    if flow is None:
        return print_mm_s
    return np.where(np.asarray(flow) == 0, settings.travel_mm_s, print_mm_s)


def moving_s(mv, settings):
    """Seconds one layer's moves ``mv`` take at their feed rates, ignoring acceleration:
    the pace the link must keep up with."""
    return float((mv["len"] / _speeds(settings.print_mm_s, mv["flow"], settings)).sum())


def summary(groups, settings, clamped_segments):
    """The report's ``gcode`` figures known before writing (``lines`` and ``bytes`` are
    filled in by the writer), from the :class:`pipeline.gcode.layers.Group` of each set of
    paths; where layer groups print their own, counts add up over the groups and
    ``moves_per_s`` is the busiest group's."""
    th_all = np.concatenate([g.th_mm.ravel() for g in groups])
    filament = sum(g.text.filament_mm for g in groups)
    lower = groups[0]
    # One set of paths may print several runs of layers: count its paths once.
    sets = list({g.role: g for g in groups}.values())
    stats = {
        "lines": 0, "bytes": 0, "layers": settings.layers,
        "thickness_mm": {"min": float(th_all.min()), "max": float(th_all.max())},
        "clamped_segments": int(clamped_segments),
        "filament_mm": round(float(filament), 3),
        "filament_g": round(float(filament_g(filament, settings)), 3),
        "estimated_print_s": round(sum(g.timing.total_s for g in groups), 1), "bed_fits": True,
        "travel_moves": sum((len(g.starts) - 1) * g.layers for g in groups),
        "traces": len(lower.starts) - 1,
        "segments": sum(len(g.q) - (len(g.starts) - 1) for g in sets),
        "extrusion_moves": sum(len(g.mv["len"]) * g.layers for g in groups),
        "path_length_mm": round(lower.timing.path_length_mm, 3),
        "moves_per_s": round(max(len(g.mv["len"]) / max(moving_s(g.mv, settings), 1e-9)
                                 for g in groups), 1),
    }
    for role in ("upper", "across"):
        g = next((g for g in groups if g.role == role), None)
        if g is not None:
            stats[role + "_traces"] = len(g.starts) - 1
    if settings.arc_tolerance_mm > 0:
        stats["arcs"] = sum(int((g.mv["kind"] != 1).sum()) * g.layers for g in groups)
    return stats


def _set_names(roles):
    """What each set of paths in the header's trace count prints."""
    if roles == ("lower", "upper"):
        return "lower / upper layer group"
    names = {"lower": "lower half along" if "upper" in roles else "along",
             "upper": "upper half along", "across": "across"}
    return " / ".join(names[r] for r in roles)


def filament_g(filament_mm, settings):
    return filament_mm * settings.filament_area_mm2 / 1000.0 * settings.filament_density_g_cm3


def header_lines(groups, settings, name, extra=()):
    """The file's opening comment lines (viewer furniture and a human summary), from the
    :class:`pipeline.gcode.layers.Group` of each set of paths."""
    layers = settings.layers
    stacks = [g.th_mm[:, 0] * layers if g.th_mm.shape[1] == 1 else g.th_mm.sum(axis=1)
              for g in groups]
    th_all = np.concatenate([g.th_mm.ravel() for g in groups])
    # Arcs bulge at most the arc tolerance past their end points: ignored here.
    xy_all = np.concatenate([np.concatenate([g.mv["end"], g.mv["start"]])
                             for g in groups]) / 1000.0
    lo_xy, hi_xy = xy_all.min(axis=0), xy_all.max(axis=0)
    f_mm = sum(g.text.filament_mm for g in groups)
    total_s = sum(g.timing.total_s for g in groups)
    area = settings.filament_area_mm2
    # Each set of paths once (one set may print several runs of layers).
    sets = {g.role: len(g.text.trace_ends) for g in groups}
    traces = " / ".join("%d" % n for n in sets.values())
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
            layers, traces + (" (%s)" % _set_names(tuple(sets)) if len(sets) > 1 else ""),
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
