"""Bilayer calibration: how far a strip curls for a thickness difference through it.

A strip whose lower layers are thinner (they shrink more) than its upper ones curls
along its paths after the bath, as a bimetal strip does:
``kappa = c * (sigma_bottom - sigma_top) / h`` (``h`` the printed thickness). Strips at
a few thickness differences, one with none, are printed; the user measures each one's
rise over a chord with a ruler; the fit is ``c`` by least squares through the origin,
the sigmas read from the profile's shrink curve. The plan's curvature program uses it.
"""

import csv
from dataclasses import dataclass

import numpy as np

from pipeline.profiles.calibration import (CalibrationError, csv_text, layout_plates,
                                           rectangle_trace, specimen_label)

LENGTH_MM = 60.0
WIDTH_MM = 10.0
COLUMNS = ("specimen", "bottom_mm", "top_mm", "repeat", "chord_mm", "rise_mm")


def thickness_pairs(shrink, layers, thickness_min_mm, thickness_max_mm, n=5, c=1.5, lever=1.0):
    """``n`` (bottom, top) layer thicknesses about the middle of the range, the first
    equal, the others with shrink differences evenly up to the one that curls a strip
    of constant ``c`` by 1.2 rad over its length: strips curl well short of a half turn
    (a ruler measures them) even where the printer's constant is twice ``c``. ``lever``:
    as in :func:`fit_c`, for strips whose thickness difference is in fewer layers.
    Returns (n, 2) mm, rounded to 1 um."""
    if n < 2:
        raise CalibrationError("need at least 2 strips, got %d" % n, code="calibration.values",
                               fix="use --values 2 or more")
    mid = 0.5 * (thickness_min_mm + thickness_max_mm)
    wanted = np.linspace(0.0, 1.2 / LENGTH_MM * layers * mid / (c * lever), n)
    d = np.linspace(0.0, thickness_max_mm - thickness_min_mm, 2001)
    sb, st = shrink.sigma(mid - d / 2), shrink.sigma(mid + d / 2)
    diff = np.maximum.accumulate(sb - st)
    pick = d[np.minimum(np.searchsorted(diff, wanted), len(d) - 1)]
    return np.round(np.stack([mid - pick / 2, mid + pick / 2], axis=1), 3)


def strips(pairs, repeats, bed_mm, gap_mm=3.0):
    """Strips on the bed: (plates of Specimen, pair of each specimen id)."""
    plates = layout_plates(pairs[:, 0], repeats, bed_mm, gap_mm=gap_mm, length_mm=LENGTH_MM,
                           width_mm=WIDTH_MM)
    by_bottom = {float(b): (float(b), float(t)) for b, t in pairs}
    pair_of = {s.id: by_bottom[float(s.thickness_mm)] for plate in plates for s in plate}
    return plates, pair_of


def strip_traces(specimens, pair_of, layers, path_width_mm):
    """Traces, per-layer thicknesses ((k - 1, layers) mm: the lower half of the layers at
    the bottom thickness, the upper half at the top one, a middle layer between) and
    labels, for ``write_thickness_gcode``."""
    half = layers // 2
    traces, thetas, labels = [], [], []
    for s in specimens:
        bottom, top = pair_of[s.id]
        per_layer = np.where(np.arange(layers) < half, bottom,
                             np.where(np.arange(layers) >= layers - half, top,
                                      0.5 * (bottom + top)))
        tr = rectangle_trace(s, path_width_mm)
        traces.append(tr)
        thetas.append(np.tile(per_layer, (len(tr) - 1, 1)))
        labels.append("%s bottom_mm=%g top_mm=%g" % (specimen_label(s), bottom, top))
    return traces, thetas, labels


def template(specimens, pair_of, profile_name):
    """The CSV to fill in after the bath, with instructions as ``#`` comments."""
    return strip_template(
        "# hostd bilayer calibration for profile %s: %d strips %g x %g mm, paths along the"
        " %g mm side, lower layers thinner than upper ones by the difference in each row."
        % (profile_name, len(specimens), LENGTH_MM, WIDTH_MM, LENGTH_MM),
        "bilayer", "", specimens, pair_of, profile_name)


def strip_template(title, kind, note, specimens, pair_of, profile_name):
    """The CSV of strips of ``kind`` (``bilayer``, ``across``) to fill in after the bath:
    ``title``, then the steps (``note`` after the measuring one) as ``#`` comments."""
    head = [
        title,
        "# 1. Print %s.gcode; %s_layout.svg shows which strip is which." % (kind, kind),
        "# 2. Bathe them at 80-90 C until they stop moving; let them cool.",
        "# 3. Lay each strip on its edge on a table. Hold a ruler across its two ends on the"
        " inside of the curl: write the distance between the ends in chord_mm and the largest"
        " gap between the ruler and the strip in rise_mm (0 for a flat strip; negative if the"
        " bed side of the strip is on the outside of the curl, the other way than expected)."
        + note,
        "# 4. hostd calibrate %s-fit %s.csv --profile %s -o %s-%s.yaml"
        % (kind, kind, profile_name, profile_name, kind),
    ]
    return csv_text(head, COLUMNS, [[s.id, "%g" % pair_of[s.id][0], "%g" % pair_of[s.id][1],
                                     s.repeat, "", ""] for s in specimens])


@dataclass
class Strip:
    specimen: str
    bottom_mm: float
    top_mm: float
    chord_mm: float
    rise_mm: float

    def curvature(self, layers):
        """1/mm of the strip's middle surface, positive when its bed side (the thinner,
        more shrinking layers) is inside the curl: the rise is measured to the inside
        face, whose circle through the ends and the middle has radius
        ``(L^2 + 4 r^2) / (8 r)``; the middle lies half the printed thickness further out."""
        r = abs(self.rise_mm)
        if r == 0:
            return 0.0
        inside = (self.chord_mm ** 2 + 4.0 * r * r) / (8.0 * r)
        return float(np.sign(self.rise_mm)) / (inside + 0.25 * layers * (self.bottom_mm
                                                                          + self.top_mm))


def read_strips(text, source=None, kind="bilayer"):
    """The measured rows of a filled-in strips CSV (``kind``: ``bilayer`` or ``across``,
    the command that wrote it): [Strip]."""
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    rows = list(csv.reader(lines))
    if not rows or tuple(c.strip() for c in rows[0]) != COLUMNS:
        raise CalibrationError("not a %s measurements file (its header should be %s)"
                               % (kind, ",".join(COLUMNS)), code="calibration.bad_header",
                               file=source, fix="give the %s.csv written by `hostd calibrate "
                                                "%s`" % (kind, kind))
    out = []
    for n, row in enumerate(rows[1:], start=2):
        cells = [c.strip() for c in row]
        if len(cells) != len(COLUMNS) or not cells[4] or not cells[5]:
            continue
        try:
            bottom, top, chord, rise = (float(cells[i]) for i in (1, 2, 4, 5))
        except ValueError:
            raise CalibrationError("row %d: %r is not a number" % (n, ",".join(cells)),
                                   code="calibration.not_a_number", file=source,
                                   where="row %d" % n, fix="write mm as plain numbers") from None
        if chord <= 0 or 2 * abs(rise) > chord:
            raise CalibrationError("row %d: a rise of %g mm over a chord of %g mm is no arc"
                                   % (n, rise, chord), code="calibration.bad_value",
                                   file=source, where="row %d" % n,
                                   fix="chord_mm > 0 and the rise at most half of it (a strip "
                                       "that curled further: print shorter strips)")
        out.append(Strip(cells[0], bottom, top, chord, rise))
    return out


def fit_c(measured, shrink, layers, lever=1.0):
    """``c`` of ``kappa = c * lever * (sigma_bottom - sigma_top) / h`` through the origin.

    measured : [Strip]; shrink : the profile's ShrinkCurve; layers : layer count;
    lever : the curl of the strip's layers that differ against a bilayer's of the same
    difference (1 for bilayer strips, whose lower and upper halves differ; less for
    strips where only two layers do, :func:`pipeline.profiles.across.lever`).
    Returns (c, rms residual in 1/mm, [(x, kappa)] the points fitted).
    """
    pts = []
    for s in measured:
        sb, st = (float(v) for v in shrink.sigma(np.array([s.bottom_mm, s.top_mm])))
        h = layers * 0.5 * (s.bottom_mm + s.top_mm)          # printed thickness
        pts.append((lever * (sb - st) / h, s.curvature(layers)))
    x = np.array([p[0] for p in pts])
    k = np.array([p[1] for p in pts])
    if np.count_nonzero(np.abs(x) > 1e-9) < 2:
        raise CalibrationError("need at least two measured strips with a thickness difference",
                               code="calibration.too_few",
                               fix="measure the curled strips too, not only the flat ones")
    c = float(np.dot(x, k) / np.dot(x, x))
    return c, float(np.sqrt(np.mean((k - c * x) ** 2))), pts
