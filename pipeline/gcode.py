"""Thickness-varying G-code from tool-path traces (paper 6.4).

Each segment's shrink ratio sigma becomes a layer thickness theta through the
profile's shrink curve; the nozzle of layer ``i_l`` (1..layers) moves at
``z = theta * i_l`` (so Z changes along a path within a layer, each G1 carrying
its own Z) and extrudes ``length * theta * path_width / filament_area`` mm of
filament. ``layers`` copies of the same 2-D paths are stacked.

Numbers are quantised before anything is derived from them: XY and thickness
to 1 um (3 decimals, so ``Z = theta * i_l`` holds exactly in the text), and E
is computed from the written (rounded) positions, so the file is consistent
with itself to E's 5 decimals. Relative E is error-diffused (each move writes
the change of the rounded running total), so rounding never accumulates.

Retraction state: the profile's start G-code is expected to leave the
filament retracted by ``retraction.length_mm`` (the shipped profiles end the
purge with a retraction), so the first trace only unretracts; the end G-code
does the final retraction.

Arc fitting (``toolpath.arc_tolerance_mm > 0``, see :mod:`pipeline.arcs`)
writes G2/G3 with the Z and E change spread along the arc, which Marlin runs
with ARC_SUPPORT (on by default in Marlin 2).

Viewer comments: Cura's ``;FLAVOR:``, ``;TIME:``, ``;Filament used:``,
``;LAYER_COUNT:``, ``;LAYER:n`` (0-based, so layer index ``i_l = n + 1``) and
``;TYPE:``; PrusaSlicer's ``;LAYER_CHANGE``/``;Z:``/``;HEIGHT:`` and its
``; filament used [mm] =`` / ``[g]`` / ``; estimated printing time`` lines.
The time estimate is :mod:`pipeline.printtime`'s trapezoid model.

Strings are built per field with vectorised integer formatting
(:mod:`pipeline.numfmt`) over all moves of a layer at once; only the travel
blocks between traces are built in a Python loop over traces.
"""

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline import __version__
from pipeline.arcs import moves_with_arcs
from pipeline.errors import PlanError
from pipeline.numfmt import fmt, format_fixed
from pipeline.printtime import (ACCELERATION_MM_S2, JUNCTION_DEVIATION_MM, MAX_Z_SPEED_MM_S,
                                estimate_time_text, polyline_time_s, trapezoid_s)

@dataclass(frozen=True)
class GcodeSettings:
    """What the G-code writer needs from a profile (all mm, mm/s, degrees C).

    Build with :meth:`from_profile`; tests may construct it directly.
    """

    bed_mm: tuple
    max_z_mm: float
    filament_mm: float
    filament_density_g_cm3: float
    path_width_mm: float
    layers: int
    thickness_min_mm: float
    thickness_max_mm: float
    print_mm_s: float
    first_layer_mm_s: float
    travel_mm_s: float
    retract_mm: float = 0.8
    retract_mm_s: float = 35.0
    z_hop_mm: float = 0.4
    relative_e: bool = True
    start_gcode: str = ""
    end_gcode: str = ""
    arc_tolerance_mm: float = 0.0
    merge_sigma: float = 0.005
    acceleration_mm_s2: float = ACCELERATION_MM_S2
    junction_deviation_mm: float = JUNCTION_DEVIATION_MM
    profile_name: str = ""
    shrink: object = field(default=None, compare=False, repr=False)

    @classmethod
    def from_profile(cls, profile, **overrides):
        """Settings from a :class:`pipeline.profile.Profile` (``overrides`` win)."""
        if isinstance(profile, cls):
            return cls(**{**profile.__dict__, **overrides})
        vals = dict(
            bed_mm=tuple(float(v) for v in profile.bed_mm), max_z_mm=float(profile.max_z_mm),
            filament_mm=float(profile.filament_mm),
            filament_density_g_cm3=float(profile.filament_density_g_cm3),
            path_width_mm=float(profile.path_width_mm), layers=int(profile.layers),
            thickness_min_mm=float(profile.thickness_mm.min),
            thickness_max_mm=float(profile.thickness_mm.max),
            print_mm_s=float(profile.speeds_mm_s.print),
            first_layer_mm_s=float(profile.speeds_mm_s.first_layer),
            travel_mm_s=float(profile.speeds_mm_s.travel),
            retract_mm=float(profile.retraction.length_mm),
            retract_mm_s=float(profile.retraction.speed_mm_s),
            z_hop_mm=float(profile.retraction.z_hop_mm),
            relative_e=profile.extrusion == "relative",
            start_gcode=profile.render_gcode("start"), end_gcode=profile.render_gcode("end"),
            arc_tolerance_mm=float(profile.toolpath.arc_tolerance_mm),
            merge_sigma=float(profile.toolpath.merge_sigma),
            profile_name=profile.name, shrink=profile.shrink_curve)
        vals.update(overrides)
        return cls(**vals)

    @property
    def filament_area_mm2(self):
        return math.pi * self.filament_mm ** 2 / 4.0


# --------------------------------------------------------------- geometry

def _prepare(traces, values, offset_mm):
    """Concatenate traces, quantise XY to um, drop zero-length segments.

    Returns ``(xy_um (n,2) int, starts (t+1,) int, seg_values list, kept (t,) int)``
    where trace i owns points ``starts[i]:starts[i+1]``, ``seg_values[j]`` are
    the kept segments' values for each per-segment array in ``values``, and
    ``kept`` the input index of each surviving trace (traces reduced to a
    single point print nothing and are dropped).
    """
    if len(traces) == 0:
        raise PlanError("no tool paths to print", code="gcode.empty",
                        fix="check the tool-path stage produced traces")
    pts = [np.asarray(t, dtype=float).reshape(-1, 2) for t in traces]
    lens = np.array([len(p) for p in pts])
    for arr in values:
        for i, (p, v) in enumerate(zip(pts, arr)):
            if len(np.asarray(v).reshape(-1)) != max(len(p) - 1, 0):
                raise PlanError("trace %d has %d points but %d per-segment values"
                                % (i, len(p), len(np.asarray(v).reshape(-1))),
                                code="gcode.bad_input", fix="give one value per segment")
    xy = np.concatenate(pts) + np.asarray(offset_mm, dtype=float)
    if not np.all(np.isfinite(xy)):
        raise PlanError("tool paths contain non-finite coordinates", code="gcode.bad_input")
    q = np.rint(xy * 1000.0).astype(np.int64)
    tid = np.repeat(np.arange(len(pts)), lens)
    first = np.zeros(len(q), bool)
    first[np.cumsum(lens)[:-1][lens[1:] > 0]] = True
    first[0] = True
    same = np.zeros(len(q), bool)
    same[1:] = np.all(q[1:] == q[:-1], axis=1) & ~first[1:]
    keep = ~same
    # Segment j of a trace ends at its point j+1: keep it if that point stays.
    seg_vals = []
    for arr in values:
        flat = np.concatenate([np.asarray(v, dtype=float).reshape(-1) for v in arr]
                              + [np.zeros(0)])
        seg_keep = keep[~first]
        seg_vals.append(flat[seg_keep])
    q, tid = q[keep], tid[keep]
    counts = np.bincount(tid, minlength=len(pts))
    good = counts >= 2
    if not good.all():
        pt_ok = good[tid]
        first_k = first[keep]
        seg_ok = pt_ok[~first_k]
        q, tid = q[pt_ok], tid[pt_ok]
        seg_vals = [v[seg_ok] for v in seg_vals]
        counts = counts[good]
    if len(counts) == 0:
        raise PlanError("all tool paths are shorter than 1 um", code="gcode.empty")
    starts = np.concatenate([[0], np.cumsum(counts)])
    return q, starts, seg_vals, np.flatnonzero(good)


def bed_overhang(traces, bed_mm, center=True):
    """How far the (centred) traces leave the bed on each side.

    Returns ``(offset_mm (2,), overhang dict side -> mm)`` with sides
    ``left`` (x < 0), ``right`` (x > bed x), ``front`` (y < 0), ``back``;
    values <= 0 mean inside.
    """
    pts = np.concatenate([np.asarray(t, dtype=float).reshape(-1, 2) for t in traces])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    bed = np.asarray(bed_mm, dtype=float)
    offset = (bed / 2.0 - (lo + hi) / 2.0) if center else np.zeros(2)
    lo, hi = lo + offset, hi + offset
    return offset, {"left": float(-lo[0]), "right": float(hi[0] - bed[0]),
                    "front": float(-lo[1]), "back": float(hi[1] - bed[1])}


def _check_bed(over, bed_mm, where="the part"):
    bad = {k: v for k, v in over.items() if v > 1e-3}
    if bad:
        side = max(bad, key=bad.get)
        sides = ", ".join("%.2f mm past the %s edge" % (bad[s], s) for s in sorted(bad))
        raise PlanError(
            "%s does not fit the %g x %g mm bed: it overhangs %s" % (where, bed_mm[0], bed_mm[1],
                                                                     sides),
            code="gcode.off_bed", where="%s edge, %.2f mm" % (side, bad[side]),
            fix="scale the model down (size_mm in its sidecar) or use a printer with a larger bed",
            details={"overhang_mm": over})


# ------------------------------------------------------------------- writer

class _Sink:
    """Counts lines and bytes of what is written to a text or binary file object."""

    def __init__(self, f):
        self.f = f
        self.lines = 0
        self.bytes = 0
        try:
            f.write("")
            self.binary = False
        except TypeError:
            self.binary = True

    def write(self, text):
        data = text.encode("utf-8")
        self.lines += text.count("\n")
        self.bytes += len(data)
        self.f.write(data if self.binary else text)


def thickness_for_sigma(sigmas, settings):
    """Layer thickness per segment from shrink ratios: ``(theta_mm, clamped)``.

    The shrink curve's inverse, clamped to the profile's thickness range.
    """
    if settings.shrink is None:
        raise PlanError("the profile has no shrink curve", code="gcode.no_shrink_curve",
                        fix="load the settings from a profile")
    theta, clamped = settings.shrink.theta(sigmas)
    lo, hi = settings.thickness_min_mm, settings.thickness_max_mm
    clamped = clamped | (theta < lo) | (theta > hi)
    return np.clip(theta, lo, hi), clamped


def write_gcode(traces, sigmas, profile, out, name="part", center=True):
    """Write thickness-varying G-code for tool-path traces (paper 6.4).

    Parameters
    ----------
    traces : list of (k_i, 2) float, mm
        Ordered tool paths in the flattened layout's coordinates.
    sigmas : list of (k_i - 1,) float
        Shrink ratio per segment.
    profile : pipeline.profile.Profile or GcodeSettings
    out : path or file object (text or binary)
        A path is written to ``path + ".part"`` and renamed when complete.
    name : str
        Job name for the header.
    center : bool
        Translate the layout's bounding-box centre to the bed centre.

    Returns
    -------
    dict with ``lines``, ``bytes``, ``layers``, ``thickness_mm {min, max}``,
    ``clamped_segments`` (per 2-D path, not times layers), ``filament_mm``,
    ``filament_g``, ``estimated_print_s``, ``bed_fits``, ``travel_moves``,
    ``traces``, ``extrusion_moves``, ``moves_per_s``, and
    ``lines_without_arcs`` when arc fitting is on.
    """
    settings = GcodeSettings.from_profile(profile)
    if len(traces) != len(sigmas):
        raise PlanError("%d traces but %d sigma arrays" % (len(traces), len(sigmas)),
                        code="gcode.bad_input", fix="give one sigma array per trace")
    flat = np.concatenate([np.asarray(s, dtype=float).reshape(-1) for s in sigmas]
                          + [np.zeros(0)])
    theta, clamped = thickness_for_sigma(flat, settings)
    parts = np.cumsum([np.asarray(s).size for s in sigmas])[:-1]
    thetas = np.split(theta, parts)
    return write_thickness_gcode(traces, thetas, settings, out, name=name, center=center,
                                 arc_values=np.split(flat, parts),
                                 arc_value_span=settings.merge_sigma,
                                 clamped_segments=int(clamped.sum()))


def write_thickness_gcode(traces, thetas_mm, settings, out, name="part", center=True,
                          labels=None, arc_values=None, arc_value_span=0.0,
                          clamped_segments=0, header_extra=()):
    """Write G-code for traces with a given layer thickness per segment.

    ``write_gcode`` without the shrink curve (calibration prints thicknesses
    directly). ``labels`` (one str per trace, or None) become ``;`` comment
    lines before each trace; ``arc_values`` (per segment, default the
    thickness) may span at most ``arc_value_span`` inside one arc. See
    :func:`write_gcode` for the other parameters and the returned stats.
    """
    settings = GcodeSettings.from_profile(settings)
    if len(traces) != len(thetas_mm):
        raise PlanError("%d traces but %d thickness arrays" % (len(traces), len(thetas_mm)),
                        code="gcode.bad_input", fix="give one thickness array per trace")
    if labels is not None:
        labels = [labels[i] for i in range(len(traces))]
    arrays = [thetas_mm] + ([arc_values] if arc_values is not None else [])
    bed = settings.bed_mm
    offset, over = bed_overhang(traces, bed, center=center)
    _check_bed(over, bed)
    q, starts, vals, kept = _prepare(traces, arrays, offset)
    if labels is not None:
        labels = [labels[i] for i in kept]
    lo_um = int(math.ceil(settings.thickness_min_mm * 1000 - 1e-6))
    hi_um = int(math.floor(settings.thickness_max_mm * 1000 + 1e-6))
    th_um = np.clip(np.rint(vals[0] * 1000.0), lo_um, hi_um).astype(np.int64)
    arc_vals = vals[1] if arc_values is not None else th_um / 1000.0
    layers = settings.layers
    top_um = int(th_um.max()) * layers + int(round(settings.z_hop_mm * 1000))
    if top_um > settings.max_z_mm * 1000:
        raise PlanError("the part needs %.3f mm of Z but the printer has %g mm"
                        % (top_um / 1000, settings.max_z_mm), code="gcode.too_tall",
                        fix="use fewer layers or thinner layers")

    mv = moves_with_arcs(q, starts, th_um, arc_vals, settings.arc_tolerance_mm, arc_value_span)
    n_traces = len(starts) - 1
    n_moves = len(mv["th"])
    n_segments = len(q) - n_traces
    area = settings.filament_area_mm2
    e_mm = mv["len"] * (mv["th"] / 1000.0) * settings.path_width_mm / area
    e_cum = np.rint(np.cumsum(e_mm) * 1e5).astype(np.int64)
    e_trace_end = e_cum[np.concatenate([mv["first"][1:], [n_moves]]) - 1]
    if settings.relative_e:
        e_strings = format_fixed(np.diff(np.concatenate([[0], e_cum])), 5, " E")
    else:
        e_strings = format_fixed(e_cum, 5, " E")
    filament_mm = e_cum[-1] / 1e5 * layers

    # Strings shared by all layers: G code, X, Y, arc centre, E.
    prev = np.empty_like(mv["end"])
    prev[1:] = mv["end"][:-1]
    prev[mv["first"]] = mv["start"]
    is_arc = mv["kind"] != 1
    code = np.array(["", "G1", "G2", "G3"], dtype=object)[mv["kind"]]
    xs = format_fixed(mv["end"][:, 0], 3, " X")
    ys = format_fixed(mv["end"][:, 1], 3, " Y")
    xs[(mv["end"][:, 0] == prev[:, 0]) & ~is_arc] = ""
    ys[(mv["end"][:, 1] == prev[:, 1]) & ~is_arc] = ""
    base = code + xs + ys
    tail = np.full(n_moves, "", dtype=object)
    if is_arc.any():
        i_s = format_fixed(mv["ij"][:, 0], 3, " I")
        j_s = format_fixed(mv["ij"][:, 1], 3, " J")
        i_s[mv["ij"][:, 0] == 0] = ""
        j_s[mv["ij"][:, 1] == 0] = ""
        tail[is_arc] = (i_s + j_s)[is_arc]
    tail = tail + e_strings
    th_prev = np.empty_like(mv["th"])
    th_prev[1:] = mv["th"][:-1]
    th_prev[mv["first"]] = mv["th"][mv["first"]]
    z_shown = mv["th"] != th_prev
    trace_ends = np.concatenate([mv["first"][1:], [n_moves]])

    # Time estimate and header numbers.
    acc = settings.acceleration_mm_s2
    jd = settings.junction_deviation_mm
    # Timed on the polyline before arc fitting (arcs change it negligibly).
    t_first, length_mm = polyline_time_s(q / 1000.0, starts, settings.first_layer_mm_s, acc, jd)
    t_rest = polyline_time_s(q / 1000.0, starts, settings.print_mm_s, acc, jd)[0]
    travel_from = np.concatenate([[[0, 0]], mv["end"][trace_ends[:-1] - 1]]) / 1000.0
    travel_to = mv["start"] / 1000.0
    travel_len = np.hypot(*(travel_to - travel_from).T)
    if layers > 1:
        wrap = np.hypot(*(travel_to[0] - mv["end"][-1] / 1000.0))
        travel_rest = travel_len.copy()
        travel_rest[0] = wrap
    else:
        travel_rest = travel_len
    v_tr = settings.travel_mm_s
    t_travel = (trapezoid_s(travel_len, 0.0, 0.0, v_tr, acc).sum()
                + (layers - 1) * trapezoid_s(travel_rest, 0.0, 0.0, v_tr, acc).sum())
    z_speed = min(v_tr, MAX_Z_SPEED_MM_S)
    t_retract = 2 * settings.retract_mm / settings.retract_mm_s if settings.retract_mm > 0 else 0
    t_hop = 2 * settings.z_hop_mm / z_speed
    t_total = (t_first + (layers - 1) * t_rest + t_travel
               + n_traces * layers * (t_retract + t_hop))
    filament_g = filament_mm * area / 1000.0 * settings.filament_density_g_cm3
    # Arcs bulge at most the arc tolerance past their end points: ignored here.
    xy_all = np.concatenate([mv["end"], mv["start"]]) / 1000.0
    th_mm = th_um / 1000.0
    stats = {
        "lines": 0, "bytes": 0, "layers": layers,
        "thickness_mm": {"min": float(th_mm.min()), "max": float(th_mm.max())},
        "clamped_segments": int(clamped_segments),
        "filament_mm": round(float(filament_mm), 3), "filament_g": round(float(filament_g), 3),
        "estimated_print_s": round(float(t_total), 1), "bed_fits": True,
        "travel_moves": n_traces * layers, "traces": n_traces, "segments": n_segments,
        "extrusion_moves": n_moves * layers, "path_length_mm": round(length_mm, 3),
        "moves_per_s": round(n_moves / max(length_mm / settings.print_mm_s, 1e-9), 1),
    }
    if settings.arc_tolerance_mm > 0:
        stats["arcs"] = int(is_arc.sum()) * layers
    lo_xy, hi_xy = xy_all.min(axis=0), xy_all.max(axis=0)
    header = [
        ";FLAVOR:Marlin",
        ";TIME:%d" % round(t_total),
        ";Filament used: %sm" % fmt(filament_mm / 1000.0, 5),
        ";LAYER_COUNT:%d" % layers,
        ";MINX:%s" % fmt(lo_xy[0]), ";MINY:%s" % fmt(lo_xy[1]),
        ";MINZ:%s" % fmt(th_mm.min()),
        ";MAXX:%s" % fmt(hi_xy[0]), ";MAXY:%s" % fmt(hi_xy[1]),
        ";MAXZ:%s" % fmt(th_mm.max() * layers),
        ";generated by hostd %s" % __version__,
        "; job: %s" % _one_line(name),
        "; profile: %s" % _one_line(settings.profile_name),
        "; layers: %d, traces per layer: %d, thickness %s..%s mm, E %s" % (
            layers, n_traces, fmt(th_mm.min()), fmt(th_mm.max()),
            "relative" if settings.relative_e else "absolute"),
        "; filament used [mm] = %.2f" % filament_mm,
        "; filament used [cm3] = %.3f" % (filament_mm * area / 1000.0),
        "; filament used [g] = %.3f" % filament_g,
        "; estimated printing time (normal mode) = %s" % estimate_time_text(t_total),
    ] + ["; " + _one_line(h) for h in header_extra]

    def emit(sink):
        sink.write("\n".join(header) + "\n")
        if settings.start_gcode:
            sink.write(settings.start_gcode.rstrip("\n") + "\n")
        sink.write("G90\n%s\n" % ("M83" if settings.relative_e else "M82"))
        state = {"retracted": settings.retract_mm > 0, "z": None, "f": None, "e": 0}
        r_um5 = int(round(settings.retract_mm * 1e5))
        f_travel = fmt(settings.travel_mm_s * 60, 1)
        f_retract = fmt(settings.retract_mm_s * 60, 1)
        f_z = fmt(z_speed * 60, 1)
        hop_um = int(round(settings.z_hop_mm * 1000))

        def feed(f):
            if state["f"] == f:
                return ""
            state["f"] = f
            return " F" + f

        def e_move(target):
            # target: E in 1e-5 mm, absolute within the layer (relative: a delta).
            return "G1 E%s%s" % (format_fixed([target], 5)[0], feed(f_retract))

        for layer in range(1, layers + 1):
            f_print = fmt((settings.first_layer_mm_s if layer == 1 else settings.print_mm_s)
                          * 60, 1)
            out = [";LAYER_CHANGE", ";Z:%s" % fmt(th_mm.max() * layer),
                   ";HEIGHT:%s" % fmt(th_mm.max()), ";LAYER:%d" % (layer - 1)]
            if not settings.relative_e:
                # E counts from 0 per layer; a retracted filament sits at -length.
                out.append("G92 E%s" % (fmt(-settings.retract_mm, 5) if state["retracted"]
                                        else "0"))
                state["e"] = 0
            sink.write("\n".join(out) + "\n")
            z_um = mv["th"] * layer
            zs = np.full(n_moves, "", dtype=object)
            zs[z_shown] = format_fixed(z_um[z_shown], 3, " Z")
            lines = base + zs + tail
            for ti in range(n_traces):
                a, b = int(mv["first"][ti]), int(trace_ends[ti])
                blk = []
                if labels is not None and labels[ti]:
                    blk.append(";" + _one_line(labels[ti]))
                z0 = int(z_um[a])
                # Travel: retract, lift above both ends plus the hop, move, lower, unretract.
                if not state["retracted"] and r_um5:
                    blk.append(e_move(-r_um5 if settings.relative_e else state["e"] - r_um5))
                    state["retracted"] = True
                zc = state["z"]
                lift = max(zc if zc is not None else z0, z0) + hop_um
                if zc is None or lift != zc:
                    blk.append("G0 Z%s%s" % (fmt(lift / 1000.0), feed(f_z)))
                sx, sy = mv["start"][ti]
                blk.append("G0 X%s Y%s%s" % (fmt(sx / 1000.0), fmt(sy / 1000.0), feed(f_travel)))
                if lift != z0:
                    blk.append("G0 Z%s%s" % (fmt(z0 / 1000.0), feed(f_z)))
                if state["retracted"] and r_um5:
                    blk.append(e_move(r_um5 if settings.relative_e else state["e"]))
                    state["retracted"] = False
                blk.append(";TYPE:SKIN")
                state["f"] = f_print
                first_line = lines[a] + " F" + f_print
                sink.write("\n".join(blk) + "\n" + first_line + "\n")
                if b > a + 1:
                    sink.write("\n".join(lines[a + 1:b].tolist()) + "\n")
                state["z"] = int(z_um[b - 1])
                state["e"] = int(e_trace_end[ti])
        if settings.end_gcode:
            sink.write(settings.end_gcode.rstrip("\n") + "\n")
        sink.write("; end of hostd job\n")

    if isinstance(out, (str, os.PathLike)):
        path = Path(out)
        tmp = path.with_name(path.name + ".part")
        try:
            with open(tmp, "w", encoding="utf-8", newline="\n", buffering=1 << 20) as f:
                sink = _Sink(f)
                emit(sink)
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()
    else:
        sink = _Sink(out)
        emit(sink)
    stats["lines"] = sink.lines
    stats["bytes"] = sink.bytes
    if settings.arc_tolerance_mm > 0:
        stats["lines_without_arcs"] = sink.lines + (n_segments - n_moves) * layers
    return stats


def _one_line(text):
    return " ".join(str(text).split())
