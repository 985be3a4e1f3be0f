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

Arc fitting (``toolpath.arc_tolerance_mm > 0``, see :mod:`pipeline.gcode.arcs`)
writes G2/G3 with the Z and E change spread along the arc, which Marlin runs
with ARC_SUPPORT (on by default in Marlin 2).

Viewer comments: Cura's ``;FLAVOR:``, ``;TIME:``, ``;Filament used:``,
``;LAYER_COUNT:``, ``;LAYER:n`` (0-based, so layer index ``i_l = n + 1``) and
``;TYPE:``; PrusaSlicer's ``;LAYER_CHANGE``/``;Z:``/``;HEIGHT:`` and its
``; filament used [mm] =`` / ``[g]`` / ``; estimated printing time`` lines.
The time estimate, figures and header are :mod:`pipeline.gcode.summary`'s; the layers'
text is :mod:`pipeline.gcode.layers`'.
"""

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import PlanError
from pipeline.gcode.arcs import moves_with_arcs
from pipeline.gcode.chords import merge_chords
from pipeline.gcode.link import feed_percent, link_moves_per_s
from pipeline.gcode.layers import Group, emit, text_of_moves
from pipeline.gcode.printtime import ACCELERATION_MM_S2, JUNCTION_DEVIATION_MM
from pipeline.gcode.summary import estimate, header_lines, summary

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
    chord_tolerance_mm: float = 0.0
    baud: int = 115200
    merge_sigma: float = 0.005
    acceleration_mm_s2: float = ACCELERATION_MM_S2
    junction_deviation_mm: float = JUNCTION_DEVIATION_MM
    profile_name: str = ""
    shrink: object = field(default=None, compare=False, repr=False)

    @classmethod
    def from_profile(cls, profile, **overrides):
        """Settings from a :class:`pipeline.profiles.schema.Profile` (``overrides`` win)."""
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
            start_gcode=profile.render_gcode("start"), end_gcode=profile.end_gcode(),
            arc_tolerance_mm=float(profile.toolpath.arc_tolerance_mm),
            chord_tolerance_mm=float(profile.toolpath.chord_tolerance_mm),
            baud=int(profile.serial.baud),
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


def write_gcode(traces, sigmas, profile, out, name="part", center=True, deltas=None,
                upper=None, dry=None):
    """Write thickness-varying G-code for tool-path traces (paper 6.4).

    Parameters
    ----------
    traces : list of (k_i, 2) float, mm
        Ordered tool paths in the flattened layout's coordinates.
    sigmas : list of (k_i - 1,) float
        Shrink ratio per segment.
    profile : pipeline.profiles.schema.Profile or GcodeSettings
    out : path or file object (text or binary)
        A path is written to ``path + ".part"`` and renamed when complete.
    name : str
        Job name for the header.
    center : bool
        Translate the layout's bounding-box centre to the bed centre.
    deltas : list of (k_i - 1,) float, optional
        A bilayer per segment: the lower half of the layers shrinks by ``sigma +
        delta / 2``, the upper half by ``sigma - delta / 2`` (a middle layer by
        ``sigma``), so the sheet curls away from its lower side where delta > 0.
    upper : (traces, sigmas, deltas[, dry]), optional
        Paths of their own for the upper half of the layers (crossed layer groups), with
        the shrink and bilayer of the triangles they cross; ``traces`` then print the
        lower half (and a middle layer).
    dry : list of (k_i - 1,) bool, optional
        Segments moved without extruding (hops over printed paths,
        :mod:`pipeline.paths.dry`): at the layer's height and the travel speed, no E,
        no retraction.

    Returns
    -------
    dict with ``lines``, ``bytes``, ``layers``, ``thickness_mm {min, max}``,
    ``clamped_segments`` (per 2-D path, not times layers), ``filament_mm``,
    ``filament_g``, ``estimated_print_s``, ``bed_fits``, ``travel_moves``,
    ``traces``, ``extrusion_moves``, ``moves_per_s`` (at the feed rates, dry moves at
    travel speed), ``link_baud``,
    ``link_moves_per_s`` (the lines per second the link carries for this file's mean
    line length), ``feed_percent`` (the feed at which the moves fit in 80 % of it), and
    ``lines_without_arcs`` when arc fitting is on; ``upper_traces`` with ``upper``.
    """
    settings = GcodeSettings.from_profile(profile)
    n = settings.layers
    if len(traces) != len(sigmas):
        raise PlanError("%d traces but %d sigma arrays" % (len(traces), len(sigmas)),
                        code="gcode.bad_input", fix="give one sigma array per trace")
    others = []
    if upper is not None:
        others.append((upper[0], _bilayer_layers(upper[1], upper[2], n),
                       range(n - n // 2 + 1, n + 1), "upper") + tuple(upper[3:4]))
    return write_laminate_gcode((traces, _bilayer_layers(sigmas, deltas, n), dry), others,
                                settings, out, name=name, center=center)


def _bilayer_layers(sigmas, deltas, layers):
    """Each trace's shrink per layer, (k - 1, layers), of a bilayer: the lower half of
    the layers at ``sigma + delta / 2``, the upper half at ``sigma - delta / 2``, a
    middle layer at ``sigma``; every layer at ``sigma`` without ``deltas``."""
    half = np.where(np.arange(layers) < layers // 2, 0.5,
                    np.where(np.arange(layers) >= layers - layers // 2, -0.5, 0.0))
    out = []
    for i, sigma in enumerate(sigmas):
        sigma = np.asarray(sigma, dtype=float).reshape(-1)
        delta = (np.zeros_like(sigma) if deltas is None
                 else np.asarray(deltas[i], dtype=float).reshape(-1))
        out.append(sigma[:, None] + delta[:, None] * half[None, :])
    return out


def write_laminate_gcode(along, others, profile, out, name="part", center=True):
    """Write G-code for a stack whose layers print several sets of paths.

    along : (traces, layer_sigmas[, dry]), traces a list of (k_i, 2) mm and layer_sigmas
    a list of (k_i - 1, layers): each segment's shrink in every layer (of the triangle it
    crosses), so that each layer's Z over every path is the sum of the thicknesses below
    it there, and dry a list of (k_i - 1,) bool, the segments moved without extruding
    (None: none); others : [(traces, layer_sigmas, layer numbers from 1, role[, dry]),
    ...], each set printing its layers (role ``upper`` or ``across`` names its count in
    the stats); ``along`` prints the layers left. Returns the stats of
    :func:`write_gcode`, with ``upper_traces`` / ``across_traces``.
    """
    settings = GcodeSettings.from_profile(profile)
    main, clamped = _layer_set(*along[:2], settings, *along[2:3])
    rest = []
    for traces, layer_sigmas, layers, role, *dry in others:
        done, more = _layer_set(traces, layer_sigmas, settings, *dry)
        rest.append(done[:3] + (layers, role, done[3]))
        clamped += more
    return write_thickness_gcode(main[0], main[1], settings, out, name=name, center=center,
                                 arc_values=main[2], arc_value_span=settings.merge_sigma,
                                 clamped_segments=clamped, others=rest, flow=main[3])


def _layer_set(traces, layer_sigmas, settings, dry=None):
    """One set of traces with a shrink per layer ready to write: ((traces, (k - 1, layers)
    thicknesses, arc values, flow: 1 extruded, 0 dry (``dry``)), clamped segments)."""
    if len(traces) != len(layer_sigmas):
        raise PlanError("%d traces but %d shrink arrays" % (len(traces), len(layer_sigmas)),
                        code="gcode.bad_input", fix="give one shrink array per trace")
    layers = settings.layers
    # The flow rides with the shrink as one more value: chords never merge across a
    # change of it (its buckets are far apart).
    values = [np.asarray(v, dtype=float).reshape(-1, layers) for v in layer_sigmas]
    flows = ([np.ones(len(v)) for v in values] if dry is None
             else [1.0 - np.asarray(d, float).reshape(-1) for d in dry])
    values = [np.column_stack([v, f]) for v, f in zip(values, flows)]
    traces, values = merge_chords(traces, values, settings.chord_tolerance_mm,
                                  settings.merge_sigma)
    parts = np.cumsum([len(v) for v in values])[:-1]
    both = np.concatenate(values + [np.zeros((0, layers + 1))])
    per_seg, flow = both[:, :layers], both[:, layers]
    theta, clamped = thickness_for_sigma(per_seg.ravel(), settings)
    theta = theta.reshape(-1, layers)
    if np.all(theta == theta[:, :1]):
        # Equal layers: one column, each layer's Z its number times the thickness (the
        # paper's), and its moves' text written once for all layers.
        theta = theta[:, :1]
    return ((traces, np.split(theta, parts), np.split(per_seg.mean(axis=1), parts),
             np.split(flow, parts)), int(clamped.reshape(-1, layers).any(axis=1).sum()))


def write_thickness_gcode(traces, thetas_mm, settings, out, name="part", center=True,
                          labels=None, arc_values=None, arc_value_span=0.0,
                          clamped_segments=0, header_extra=(), others=(), flow=None):
    """Write G-code for traces with a given layer thickness per segment.

    ``write_gcode`` without the shrink curve (calibration prints thicknesses
    directly). A trace's thickness array is (k - 1,) for equal layers or
    (k - 1, layers) for a thickness per layer; each layer's Z is then the sum of
    the thicknesses below it. ``labels`` (one str per trace, or None) become ``;`` comment
    lines before each trace; ``arc_values`` (per segment, default the
    thickness) may span at most ``arc_value_span`` inside one arc; ``flow`` (per trace,
    (k - 1,): 1 extruded, 0 dry; default all 1) scales each segment's E. Each of
    ``others`` (traces, thicknesses, arc values, layer numbers from 1, role: ``upper`` or
    ``across``[, flow]) prints its layers; ``traces`` print the layers left.
    See :func:`write_gcode` for the other parameters and the returned stats.
    """
    settings = GcodeSettings.from_profile(settings)
    n = settings.layers
    others = list(others)
    # Each other set prints its own layers; the traces given first print the rest.
    taken = {int(k) for o in others for k in o[3]}
    sets = [(traces, thetas_mm, labels, arc_values,
             _runs([k for k in range(1, n + 1) if k not in taken]), "lower", flow)]
    sets += [(tr, th, None, arc, _runs(sorted(int(k) for k in ks)), role, fl[0] if fl else None)
             for tr, th, arc, ks, role, *fl in others]
    for tr, th, _, _, _, _, _ in sets:
        if len(tr) != len(th):
            raise PlanError("%d traces but %d thickness arrays" % (len(tr), len(th)),
                            code="gcode.bad_input", fix="give one thickness array per trace")
    offset, over = bed_overhang([t for st in sets for t in st[0]], settings.bed_mm,
                                center=center)
    _check_bed(over, settings.bed_mm)
    groups = []
    for tr, th, lab, arc, spans, role, fl in sets:
        mv, q, starts, th_um, lab, seg_flow = _layer_moves(tr, th, settings, offset, lab, arc,
                                                           arc_value_span, fl)
        for span in spans:
            g = Group(mv=mv, text=text_of_moves(mv, settings, span), first=span[0],
                      last=span[1], labels=lab, q=q, starts=starts, th_mm=th_um / 1000.0,
                      role=role)
            g.timing = estimate(q, starts, mv, g.text, settings, span, seg_flow)
            groups.append(g)
    stats = summary(groups, settings, clamped_segments)
    header = header_lines(groups, settings, name, header_extra)
    sink = _write(out, lambda sink: emit(sink, header, groups, groups[0].timing, settings))
    stats["lines"] = sink.lines
    stats["bytes"] = sink.bytes
    stats["link_baud"] = settings.baud
    stats["link_moves_per_s"] = round(link_moves_per_s(settings.baud, sink.bytes, sink.lines), 1)
    stats["feed_percent"] = feed_percent(stats["moves_per_s"], stats["link_moves_per_s"])
    if settings.arc_tolerance_mm > 0:
        moves_saved = sum((len(g.q) - (len(g.starts) - 1) - len(g.mv["len"])) * g.layers
                          for g in groups)
        stats["lines_without_arcs"] = sink.lines + moves_saved
    return stats


def _runs(layers):
    """Sorted layer numbers as runs of consecutive ones: [(first, last), ...]."""
    runs = []
    for k in layers:
        if runs and runs[-1][1] == k - 1:
            runs[-1] = (runs[-1][0], k)
        else:
            runs.append((k, k))
    return runs


def _layer_moves(traces, thetas_mm, settings, offset, labels, arc_values, arc_value_span,
                 flow=None):
    """One layer's moves: traces placed on the bed (shifted by ``offset`` mm), quantised,
    thickness in whole um, runs of chords fitted by arcs. Returns ``(mv, q, starts, th_um,
    labels, seg_flow)`` (see :func:`pipeline.gcode.arcs.moves_with_arcs` for ``mv``; th_um
    (segments, K) int, K = 1 for equal layers, else one column per layer; labels of kept
    traces; seg_flow (segments,) each segment's flow); ``flow`` as
    :func:`write_thickness_gcode`'s."""
    if labels is not None:
        labels = [labels[i] for i in range(len(traces))]
    columns = _layer_columns(thetas_mm, settings.layers)
    arrays = columns + [flow if flow is not None else [np.ones(max(len(t) - 1, 0))
                                                       for t in traces]]
    arrays += [arc_values] if arc_values is not None else []
    q, starts, vals, kept = _prepare(traces, arrays, offset)
    if labels is not None:
        labels = [labels[i] for i in kept]
    lo_um = int(math.ceil(settings.thickness_min_mm * 1000 - 1e-6))
    hi_um = int(math.floor(settings.thickness_max_mm * 1000 + 1e-6))
    k = len(columns)
    th_um = np.clip(np.rint(np.stack(vals[:k], axis=1) * 1000.0), lo_um, hi_um).astype(np.int64)
    seg_flow = vals[k]
    arc_vals = vals[k + 1] if arc_values is not None else th_um.mean(axis=1) / 1000.0
    top_um = int(stack_height(th_um, settings.layers).max()) + int(round(settings.z_hop_mm * 1000))
    if top_um > settings.max_z_mm * 1000:
        raise PlanError("the part needs %.3f mm of Z but the printer has %g mm"
                        % (top_um / 1000, settings.max_z_mm), code="gcode.too_tall",
                        fix="use fewer layers or thinner layers")
    mv = moves_with_arcs(q, starts, th_um, arc_vals, settings.arc_tolerance_mm, arc_value_span,
                         seg_flow)
    return mv, q, starts, th_um, labels, seg_flow


def _layer_columns(thetas_mm, layers):
    """Per-trace thickness arrays as K lists of per-trace columns (K = 1 or ``layers``)."""
    arrs = [np.asarray(t, dtype=float) for t in thetas_mm]
    k = max([a.shape[1] for a in arrs if a.ndim == 2] or [1])
    if k not in (1, layers):
        raise PlanError("thickness arrays have %d columns for %d layers" % (k, layers),
                        code="gcode.bad_input", fix="give one column per layer, or one for all")
    if k == 1:
        return [[a.reshape(-1) for a in arrs]]
    return [[(a[:, j] if a.ndim == 2 else a) for a in arrs] for j in range(k)]


def stack_height(th_um, layers):
    """Height of the whole stack over each segment: (segments,) from (segments, K)."""
    return th_um[:, 0] * layers if th_um.shape[1] == 1 else th_um.sum(axis=1)


def _write(out, emit_to):
    """Run ``emit_to(sink)`` into ``out`` (a path, written whole or not at all, or a file
    object); returns the :class:`_Sink` with its line and byte counts."""
    if not isinstance(out, (str, os.PathLike)):
        sink = _Sink(out)
        emit_to(sink)
        return sink
    path = Path(out)
    tmp = path.with_name(path.name + ".part")
    try:
        with open(tmp, "w", encoding="utf-8", newline="\n", buffering=1 << 20) as f:
            sink = _Sink(f)
            emit_to(sink)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return sink


