"""A small G-code parser of our own, for checking what hostd writes.

Independent of ``pipeline.gcode.writer`` on purpose: it tracks the machine state the
way Marlin does (G90/G91 also switch E, M82/M83 switch E only; axes are modal;
G92 sets positions; G28 homes to 0) and records every motion as a
:class:`Move`. ``;LAYER:n`` comments (Cura's, 0-based) set the layer index
``n + 1`` that later moves carry; header comments (``;KEY:value`` and
PrusaSlicer's ``; key = value``) are collected.
"""

import math
import re
from dataclasses import dataclass, field

import numpy as np

_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class Move:
    """One G0/G1/G2/G3 line.

    ``start``/``end`` are (x, y, z) in mm; ``e`` is the filament pushed (mm,
    negative for a retraction); ``center`` is the arc centre (x, y) for G2/G3.
    """

    code: int
    start: tuple
    end: tuple
    e: float
    f: float
    layer: int
    line_no: int
    center: tuple = None

    @property
    def xy_moved(self):
        return self.start[0] != self.end[0] or self.start[1] != self.end[1] or self.code in (2, 3)

    @property
    def extruding(self):
        return self.e > 0 and self.xy_moved

    @property
    def travel(self):
        return self.xy_moved and self.e <= 0

    def xy_length(self):
        """Length of the XY path (arc length for G2/G3)."""
        if self.code in (2, 3):
            return arc_radius(self) * arc_sweep(self)
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])


@dataclass
class Parsed:
    moves: list = field(default_factory=list)
    header: dict = field(default_factory=dict)
    layer_comments: list = field(default_factory=list)
    comments: list = field(default_factory=list)
    lines: int = 0

    def layer_moves(self, layer):
        return [m for m in self.moves if m.layer == layer]

    def runs(self, layer=None):
        """Extrusion runs: maximal sequences of extruding moves between travels."""
        out, cur = [], []
        for m in self.moves:
            if layer is not None and m.layer != layer:
                continue
            if m.extruding:
                cur.append(m)
            elif m.travel and cur:
                out.append(cur)
                cur = []
        if cur:
            out.append(cur)
        return out

    def travels(self, layer=None):
        return [m for m in self.moves if m.travel and m.code == 0
                and (layer is None or m.layer == layer)]


def parse(text):
    """Parse G-code text into a :class:`Parsed`."""
    pos = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
    abs_xyz, abs_e = True, True
    f = 0.0
    layer = None
    out = Parsed()
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    out.lines = len(lines)
    for no, raw in enumerate(lines, 1):
        code_part, _, comment = raw.partition(";")
        comment = comment.strip()
        if raw.lstrip().startswith(";"):
            out.comments.append(comment)
            m = re.match(r"LAYER:(-?\d+)$", comment)
            if m:
                layer = int(m.group(1)) + 1
                out.layer_comments.append(layer)
            m = re.match(r"([A-Za-z_ ]+):(.*)$", comment)
            if m and m.group(1) not in out.header:
                out.header[m.group(1)] = m.group(2).strip()
            m = re.match(r"([^=]+?)\s*=\s*(.*)$", comment)
            if m and m.group(1) not in out.header:
                out.header[m.group(1)] = m.group(2).strip()
        words = _WORD.findall(code_part)
        if not words:
            continue
        letter, num = words[0][0].upper(), words[0][1]
        args = {}
        for k, v in words[1:]:
            args[k.upper()] = float(v)
        cmd = letter + str(int(float(num)))
        if cmd == "G90":
            abs_xyz = abs_e = True
        elif cmd == "G91":
            abs_xyz = abs_e = False
        elif cmd == "M82":
            abs_e = True
        elif cmd == "M83":
            abs_e = False
        elif cmd == "G92":
            for k in "XYZE":
                if k in args:
                    pos[k] = args[k]
            if not args:
                pos = dict.fromkeys(pos, 0.0)
        elif cmd == "G28":
            for k in "XYZ":
                if not args or k in args:
                    pos[k] = 0.0
        elif cmd in ("G0", "G1", "G2", "G3"):
            start = (pos["X"], pos["Y"], pos["Z"])
            new = dict(pos)
            for k in "XYZ":
                if k in args:
                    new[k] = args[k] if abs_xyz else pos[k] + args[k]
            e = 0.0
            if "E" in args:
                e = args["E"] - pos["E"] if abs_e else args["E"]
                new["E"] = pos["E"] + e
            if "F" in args:
                f = args["F"]
            center = None
            code = int(float(num))
            if code in (2, 3):
                if "R" in args:
                    raise ValueError("line %d: R-form arcs are not parsed" % no)
                center = (start[0] + args.get("I", 0.0), start[1] + args.get("J", 0.0))
            out.moves.append(Move(code, start, (new["X"], new["Y"], new["Z"]), e, f, layer, no,
                                  center))
            pos = new
    return out


def arc_radius(m):
    return math.hypot(m.start[0] - m.center[0], m.start[1] - m.center[1])


def arc_sweep(m):
    """Angle swept by a G2/G3 move, radians (full circle when it ends where it starts)."""
    a0 = math.atan2(m.start[1] - m.center[1], m.start[0] - m.center[0])
    a1 = math.atan2(m.end[1] - m.center[1], m.end[0] - m.center[0])
    s = (a1 - a0) if m.code == 3 else (a0 - a1)
    s %= 2 * math.pi
    return s if s > 1e-9 else 2 * math.pi


def sample_move(m, step_mm=0.05):
    """Points (n, 3) along a move, arcs interpolated with linear Z (helical)."""
    if m.code not in (2, 3):
        return np.array([m.start, m.end], dtype=float)
    r = arc_radius(m)
    sweep = arc_sweep(m)
    n = max(int(math.ceil(r * sweep / step_mm)), 2)
    t = np.linspace(0.0, 1.0, n + 1)
    a0 = math.atan2(m.start[1] - m.center[1], m.start[0] - m.center[0])
    a = a0 + (sweep if m.code == 3 else -sweep) * t
    pts = np.stack([m.center[0] + r * np.cos(a), m.center[1] + r * np.sin(a),
                    m.start[2] + (m.end[2] - m.start[2]) * t], axis=1)
    pts[-1] = m.end
    return pts


def point_polyline_distance(points, poly, near_mm=None):
    """Distance from each of ``points`` (n, 2) to the polyline ``poly`` (k, 2).

    With ``near_mm``, only segments within that distance of the points'
    bounding box are considered (exact for distances up to ``near_mm``).
    """
    a, b = poly[:-1], poly[1:]
    if near_mm is not None:
        lo, hi = points.min(0) - near_mm, points.max(0) + near_mm
        keep = np.all((np.maximum(a, b) >= lo) & (np.minimum(a, b) <= hi), axis=1)
        a, b = a[keep], b[keep]
    ab = b - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    ap = points[:, None, :] - a[None]
    t = np.clip(np.einsum("nki,ki->nk", ap, ab) / ab2, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2).min(axis=1)
