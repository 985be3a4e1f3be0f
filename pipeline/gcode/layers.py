"""The body of a G-code file: every layer's moves as text, with the travel between traces.

Strings are built per field with vectorised integer formatting
(:mod:`pipeline.gcode.numfmt`) over all moves of a layer at once and shared by all
layers of a thickness group (only Z differs), one group's at a time; only the travel
blocks between traces are built in a Python loop over traces.
"""

from dataclasses import dataclass

import numpy as np

from pipeline.gcode.numfmt import fmt, format_fixed
from pipeline.gcode.summary import one_line


@dataclass
class MoveText:
    """One layer's trace bounds and E, shared by every layer of a thickness group; its
    strings are made by :func:`move_strings` only while its layers are written (a
    248 mm terrain's six layers held 75 MB of them at once).

    trace_ends : (t,) int, one past each trace's last move; e_cum : column -> (m,) int,
    the E at each move's end in 1e-5 mm (cumulative over the layer) for each thickness
    column of ``mv["th"]`` its layers print; e_trace_end : column -> (t,) int, E at each
    trace's end in 1e-5 mm; filament_mm : its layers' filament, mm.
    """

    trace_ends: np.ndarray
    e_cum: dict
    e_trace_end: dict
    filament_mm: float


def text_of_moves(mv, settings, layers=None):
    """:class:`MoveText` of one layer's moves ``mv`` (see :mod:`pipeline.gcode.arcs`),
    for the layers ``(first, last)`` (1-based, inclusive; default all) that print them."""
    first, last = layers or (1, settings.layers)
    n_moves = len(mv["len"])
    trace_ends = np.concatenate([mv["first"][1:], [n_moves]])
    e_cums, e_ends, filament = {}, {}, 0.0
    k = mv["th"].shape[1]
    cols = [0] if k == 1 else range(first - 1, last)
    for col in cols:
        e_mm = (mv["len"] * (mv["th"][:, col] / 1000.0) * settings.path_width_mm
                / settings.filament_area_mm2 * mv["flow"])
        e_cum = np.rint(np.cumsum(e_mm) * 1e5).astype(np.int64)
        e_cums[col] = e_cum
        e_ends[col] = e_cum[trace_ends - 1]
        filament += e_cum[-1] / 1e5 * (last - first + 1 if k == 1 else 1)
    return MoveText(trace_ends=trace_ends, e_cum=e_cums, e_trace_end=e_ends,
                    filament_mm=filament)


def move_strings(mv, text, settings):
    """The strings of one layer's moves ``mv`` with its :class:`MoveText` ``text``:
    (base, tails), base (m,) object, ``G1 X.. Y..`` of each move (every layer); tails :
    column -> (m,) object, `` I.. J.. E..`` of each move for each column of
    ``text.e_cum``."""
    n_moves = len(mv["len"])
    prev = np.empty_like(mv["end"])
    prev[1:] = mv["end"][:-1]
    prev[mv["first"]] = mv["start"]
    is_arc = mv["kind"] != 1
    code = np.array(["", "G1", "G2", "G3"], dtype=object)[mv["kind"]]
    xs = format_fixed(mv["end"][:, 0], 3, " X")
    ys = format_fixed(mv["end"][:, 1], 3, " Y")
    xs[(mv["end"][:, 0] == prev[:, 0]) & ~is_arc] = ""
    ys[(mv["end"][:, 1] == prev[:, 1]) & ~is_arc] = ""
    ij = np.full(n_moves, "", dtype=object)
    if is_arc.any():
        i_s = format_fixed(mv["ij"][:, 0], 3, " I")
        j_s = format_fixed(mv["ij"][:, 1], 3, " J")
        i_s[mv["ij"][:, 0] == 0] = ""
        j_s[mv["ij"][:, 1] == 0] = ""
        ij[is_arc] = (i_s + j_s)[is_arc]
    tails = {}
    for col, e_cum in text.e_cum.items():
        if settings.relative_e:
            e_strings = format_fixed(np.diff(np.concatenate([[0], e_cum])), 5, " E")
        else:
            e_strings = format_fixed(e_cum, 5, " E")
        # A dry move (a hop over printed paths) carries no E: the nozzle moves on.
        e_strings[mv["flow"] == 0] = ""
        tails[col] = ij + e_strings
    return code + xs + ys, tails


@dataclass
class Group:
    """Moves printed by the layers ``first..last`` (1-based, inclusive): crossed layer
    groups print their own paths. mv : one layer's moves; text : :class:`MoveText`;
    labels : one comment per trace, or None; q : (n, 2) int um, the layer's points;
    starts : (t + 1,) int, trace i owns ``q[starts[i]:starts[i + 1]]``; th_mm : (s, K)
    each segment's thickness; timing : its layers' estimate
    (:class:`pipeline.gcode.summary.Timing`); role : ``lower`` (the plan's paths),
    ``upper`` (the upper layer group's own) or ``across`` (the layers across the others')."""

    mv: dict
    text: MoveText
    first: int
    last: int
    labels: list = None
    q: np.ndarray = None
    starts: np.ndarray = None
    th_mm: np.ndarray = None
    timing: object = None
    role: str = "lower"

    @property
    def layers(self):
        return self.last - self.first + 1


def layer_z_um(th_um, layer):
    """Nozzle height of every move in layer ``layer`` (1-based): the sum of the
    thicknesses below and of its own, (m,) int um from (m, K) thicknesses."""
    if th_um.shape[1] == 1:
        return th_um[:, 0] * layer
    return th_um[:, :layer].sum(axis=1)


def emit(sink, header, groups, timing, settings):
    """Write the whole file to ``sink``: header, start G-code, every layer (each from the
    :class:`Group` that prints it), end G-code."""
    sink.write("\n".join(header) + "\n")
    if settings.start_gcode:
        sink.write(settings.start_gcode.rstrip("\n") + "\n")
    sink.write("G90\n%s\n" % ("M83" if settings.relative_e else "M82"))
    travel = _Travel(settings, timing.z_speed_mm_s)
    made = None
    for layer in range(1, settings.layers + 1):
        g = next(g for g in groups if g.first <= layer <= g.last)
        if made is None or made[0] is not g:
            # A group's layers are consecutive: its strings are made at its first layer
            # and the last group's dropped first, so one group's are alive at a time.
            made = None
            made = (g, move_strings(g.mv, g.text, settings))
        th = g.mv["th"]
        col = min(layer, th.shape[1]) - 1
        top_mm = layer_z_um(th, layer).max() / 1000.0
        sink.write("\n".join(travel.layer_head(layer, top_mm, th[:, col].max() / 1000.0)) + "\n")
        _emit_layer(sink, layer, g.mv, g.text, made[1], travel, g.labels)
    if settings.end_gcode:
        sink.write(settings.end_gcode.rstrip("\n") + "\n")
    sink.write("; end of hostd job\n")


def _emit_layer(sink, layer, mv, text, strings, travel, labels):
    col = min(layer, mv["th"].shape[1]) - 1
    z_um = layer_z_um(mv["th"], layer)
    # Z is written where it changes from the previous move of the same trace.
    z_prev = np.empty_like(z_um)
    z_prev[1:] = z_um[:-1]
    z_prev[mv["first"]] = z_um[mv["first"]]
    shown = z_um != z_prev
    zs = np.full(len(z_um), "", dtype=object)
    zs[shown] = format_fixed(z_um[shown], 3, " Z")
    f_print = travel.print_feed(layer)
    fs, feeds = _feeds(mv, f_print, travel.f_travel)
    base, tails = strings
    lines = base + zs + tails[col] + fs
    for ti in range(len(text.trace_ends)):
        a, b = int(mv["first"][ti]), int(text.trace_ends[ti])
        blk = [";" + one_line(labels[ti])] if labels is not None and labels[ti] else []
        blk += travel.to_trace(int(z_um[a]), mv["start"][ti])
        blk.append(";TYPE:SKIN")
        sink.write("\n".join(blk) + "\n" + "\n".join(lines[a:b].tolist()) + "\n")
        travel.f = feeds[b - 1]
        travel.z = int(z_um[b - 1])
        travel.e = int(text.e_trace_end[col][ti])


def _feeds(mv, f_print, f_travel):
    """The `` F..`` word of each move, where the feed rate changes, and the feed each move
    runs at: dry moves at the travel speed, as a slicer's combing moves over infill, so
    the nozzle oozes for as short a time as it can. Every trace's first move sets it."""
    dry = mv["flow"] == 0
    changed = np.ones(len(dry), bool)
    changed[1:] = dry[1:] != dry[:-1]
    changed[mv["first"]] = True
    feeds = np.where(dry, f_travel, f_print).astype(object)
    fs = np.full(len(dry), "", dtype=object)
    fs[changed] = " F" + feeds[changed]
    return fs, feeds


class _Travel:
    """The nozzle's state between traces (retracted, Z, feed rate, E) and the moves that
    carry it from one trace's end to the next one's start."""

    def __init__(self, settings, z_speed_mm_s):
        self.s = settings
        self.retracted = settings.retract_mm > 0
        self.z = None
        self.f = None
        self.e = 0
        self.r_um5 = int(round(settings.retract_mm * 1e5))
        self.f_travel = fmt(settings.travel_mm_s * 60, 1)
        self.f_retract = fmt(settings.retract_mm_s * 60, 1)
        self.f_z = fmt(z_speed_mm_s * 60, 1)
        self.hop_um = int(round(settings.z_hop_mm * 1000))

    def print_feed(self, layer):
        return fmt((self.s.first_layer_mm_s if layer == 1 else self.s.print_mm_s) * 60, 1)

    def layer_head(self, layer, top_mm, height_mm):
        out = [";LAYER_CHANGE", ";Z:%s" % fmt(top_mm),
               ";HEIGHT:%s" % fmt(height_mm), ";LAYER:%d" % (layer - 1)]
        if not self.s.relative_e:
            # E counts from 0 per layer; a retracted filament sits at -length.
            out.append("G92 E%s" % (fmt(-self.s.retract_mm, 5) if self.retracted else "0"))
            self.e = 0
        return out

    def _feed(self, f):
        if self.f == f:
            return ""
        self.f = f
        return " F" + f

    def _e_move(self, target):
        # target: E in 1e-5 mm, absolute within the layer (relative: a delta).
        return "G1 E%s%s" % (format_fixed([target], 5)[0], self._feed(self.f_retract))

    def to_trace(self, z0, start_um):
        """Retract, lift above both ends plus the hop, move, lower, unretract."""
        blk = []
        relative = self.s.relative_e
        if not self.retracted and self.r_um5:
            blk.append(self._e_move(-self.r_um5 if relative else self.e - self.r_um5))
            self.retracted = True
        zc = self.z
        lift = max(zc if zc is not None else z0, z0) + self.hop_um
        if zc is None or lift != zc:
            blk.append("G0 Z%s%s" % (fmt(lift / 1000.0), self._feed(self.f_z)))
        sx, sy = start_um
        blk.append("G0 X%s Y%s%s" % (fmt(sx / 1000.0), fmt(sy / 1000.0), self._feed(self.f_travel)))
        if lift != z0:
            blk.append("G0 Z%s%s" % (fmt(z0 / 1000.0), self._feed(self.f_z)))
        if self.retracted and self.r_um5:
            blk.append(self._e_move(self.r_um5 if relative else self.e))
            self.retracted = False
        return blk
