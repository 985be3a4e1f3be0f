"""Material characterisation (paper section 6, Fig. 2): print, measure, fit.

Print rectangles of parallel paths (55 x 20 mm, ``layers`` layers) at evenly
spaced layer thicknesses with a few repeats each; after the hot-water bath a
person measures each rectangle's length along its paths. The shrink per
specimen is ``1 - measured / printed``; the per-thickness means are fitted with
the profile's polynomial (:class:`pipeline.profiles.shrink.ShrinkCurve`) and become the
profile's new ``shrink_curve``.

A rectangle's printed length is its outer length along the paths (the bead
ends included): path centrelines run ``length - path_width``.
"""

import csv
import io
from dataclasses import dataclass

import numpy as np

from pipeline.errors import InvalidProfile, PipelineError, PlanError
from pipeline.profiles.shrink import ShrinkCurve

LENGTH_MM = 55.0
WIDTH_MM = 20.0
COLUMNS = ("specimen", "thickness_mm", "repeat", "printed_length_mm", "measured_length_mm")
# A caliper reading may exceed the printed length by this fraction (0.11 mm on
# 55 mm) at zero shrink before it counts as growth.
GROWTH_TOLERANCE = 0.002
# Repeats of one thickness whose shrink differs by more than this are suspect.
MAX_REPEAT_SPREAD = 0.05
# Mean shrink may rise with thickness by this much (noise near zero shrink).
MONOTONIC_TOLERANCE = 0.01


@dataclass(frozen=True)
class Specimen:
    """One calibration rectangle on the bed.

    ``x_mm, y_mm`` is its front-left outer corner in bed coordinates; paths
    run along x when ``along == "x"`` (else along y).
    """

    id: int
    thickness_mm: float
    repeat: int
    x_mm: float
    y_mm: float
    length_mm: float = LENGTH_MM
    width_mm: float = WIDTH_MM
    along: str = "x"

    @property
    def size_xy_mm(self):
        if self.along == "x":
            return self.length_mm, self.width_mm
        return self.width_mm, self.length_mm


class CalibrationError(PipelineError):
    """Calibration measurements that cannot be fitted."""

    default_code = "calibration.invalid"


def thickness_values(thickness_min_mm, thickness_max_mm, n):
    """``n`` thicknesses evenly across the range, rounded to 1 um: (n,) float, mm."""
    if n < 2:
        raise PlanError("need at least 2 thickness values, got %d" % n,
                        code="calibration.values", fix="use --values 2 or more (paper: 11)")
    return np.round(np.linspace(thickness_min_mm, thickness_max_mm, n), 3)


def layout_plates(thicknesses_mm, repeats, bed_mm, plates=None, gap_mm=3.0, margin_mm=3.0,
                  length_mm=LENGTH_MM, width_mm=WIDTH_MM):
    """Place ``len(thicknesses) * repeats`` rectangles on one or more bed loads.

    Specimens are numbered 1.. repeat by repeat (all thicknesses of repeat 1
    first), then row by row from the front-left of each plate, so repeats land
    on different parts of the bed (or on different plates). Each plate is a
    grid centred on the bed, paths along x or y, whichever holds more. The
    paper's 33 rectangles need a ~250 x 230 mm bed; smaller beds take two
    plates.

    Parameters
    ----------
    plates : int, optional
        Number of plates to use; default: as few as hold them all.

    Returns
    -------
    list (plates) of list of :class:`Specimen`. Raises ``PlanError`` code
    ``calibration.bed_too_small`` when they do not fit in ``plates`` plates
    (or a single rectangle does not fit the bed).
    """
    th = [float(t) for t in thicknesses_mm]
    if repeats < 1:
        raise PlanError("need at least 1 repeat", code="calibration.values",
                        fix="use --repeats 1 or more (paper: 3)")
    n = len(th) * int(repeats)
    usable = np.asarray(bed_mm, dtype=float) - 2 * margin_mm
    options = []
    for along, (sx, sy) in (("x", (length_mm, width_mm)), ("y", (width_mm, length_mm))):
        cols = max(int((usable[0] + gap_mm) // (sx + gap_mm)), 0)
        rows = max(int((usable[1] + gap_mm) // (sy + gap_mm)), 0)
        options.append((cols * rows, along, sx, sy, cols))
    cap, along, sx, sy, cols = max(options, key=lambda o: o[0])
    need = -(-n // cap) if cap else None
    if cap == 0 or (plates is not None and need > plates):
        raise PlanError(
            "%d calibration rectangles of %g x %g mm do not fit %s of the %g x %g mm bed (%d "
            "per plate with %g mm gaps and %g mm margins)"
            % (n, length_mm, width_mm, "%d load(s)" % plates if plates else "one load",
               bed_mm[0], bed_mm[1], cap, gap_mm, margin_mm),
            code="calibration.bed_too_small",
            fix="print fewer (--values, --repeats) or allow more plates (--plates)"
            if cap else "the bed is smaller than one %g x %g mm rectangle" % (length_mm, width_mm))
    n_plates = min(max(need, plates or 1), n)
    per = -(-n // n_plates)
    out = []
    for p in range(n_plates):
        ids = range(p * per, min((p + 1) * per, n))
        m = len(ids)
        rows_used = -(-m // cols)
        cols_used = min(cols, m)
        x0 = (bed_mm[0] - (cols_used * sx + (cols_used - 1) * gap_mm)) / 2
        y0 = (bed_mm[1] - (rows_used * sy + (rows_used - 1) * gap_mm)) / 2
        plate = []
        for j, k in enumerate(ids):
            r, c = divmod(j, cols)
            plate.append(Specimen(id=k + 1, thickness_mm=th[k % len(th)],
                                  repeat=k // len(th) + 1,
                                  x_mm=round(x0 + c * (sx + gap_mm), 3),
                                  y_mm=round(y0 + r * (sy + gap_mm), 3),
                                  length_mm=length_mm, width_mm=width_mm, along=along))
        out.append(plate)
    return out


def rectangle_trace(specimen, path_width_mm):
    """One continuous boustrophedon trace filling a specimen: (k, 2) float, mm.

    ``round(width / path_width)`` parallel paths ``path_width`` apart, joined
    at alternate ends, centrelines inset by half a path width.
    """
    w = path_width_mm
    n = max(int(round(specimen.width_mm / w)), 1)
    a = np.array([w / 2, specimen.length_mm - w / 2])
    rows = []
    for j in range(n):
        along = a if j % 2 == 0 else a[::-1]
        across = np.full(2, w / 2 + j * w)
        rows.append(np.stack([along, across], axis=1))
    pts = np.concatenate(rows)
    if specimen.along == "y":
        pts = pts[:, ::-1]
    return pts + np.array([specimen.x_mm, specimen.y_mm])


def specimen_label(s):
    return "SPECIMEN:%d thickness_mm=%g repeat=%d" % (s.id, s.thickness_mm, s.repeat)


def calibration_traces(specimens, path_width_mm):
    """Traces, per-segment thicknesses and labels for ``write_thickness_gcode``."""
    traces = [rectangle_trace(s, path_width_mm) for s in specimens]
    thetas = [np.full(len(t) - 1, s.thickness_mm) for t, s in zip(traces, specimens)]
    return traces, thetas, [specimen_label(s) for s in specimens]


def layout_svg(plates, bed_mm, title=""):
    """SVG (mm units) of each plate's rectangles with their specimen numbers: str.

    ``plates`` is :func:`layout_plates`' result; plates are drawn one below
    the other, each with the bed's front edge at the bottom.
    """
    bx, by = float(bed_mm[0]), float(bed_mm[1])
    band = by + 14
    height = band * len(plates) + 6
    out = ['<svg xmlns="http://www.w3.org/2000/svg" width="%gmm" height="%gmm" '
           'viewBox="0 0 %g %g" font-family="sans-serif">' % (bx, height, bx, height),
           '<title>%s</title>' % _xml(title or "hostd calibration layout"),
           '<text x="2" y="4" font-size="3.5">%s</text>' % _xml(title)]
    for p, plate in enumerate(plates):
        oy = 6 + p * band
        out.append('<text x="2" y="%g" font-size="3">plate %d of %d (bed front at the bottom; '
                   'number = specimen, then thickness and repeat)</text>'
                   % (oy + 3, p + 1, len(plates)))
        out.append('<rect x="0" y="%g" width="%g" height="%g" fill="#f4f4f4" stroke="#333" '
                   'stroke-width="0.5"/>' % (oy + 5, bx, by))
        for s in plate:
            sx, sy = s.size_xy_mm
            top = oy + 5 + by - (s.y_mm + sy)  # SVG y grows down, bed y grows to the back
            out.append('<rect x="%g" y="%g" width="%g" height="%g" fill="#cde" stroke="#246" '
                       'stroke-width="0.3"><title>%s</title></rect>'
                       % (s.x_mm, top, sx, sy, _xml(specimen_label(s))))
            cx, cy = s.x_mm + sx / 2, top + sy / 2
            fs = min(sx, sy) * 0.35
            out.append('<text x="%g" y="%g" font-size="%g" text-anchor="middle">%d</text>'
                       % (cx, cy, fs, s.id))
            out.append('<text x="%g" y="%g" font-size="%g" text-anchor="middle">%g mm r%d'
                       '</text>' % (cx, cy + fs * 0.75, fs * 0.45, s.thickness_mm, s.repeat))
    out.append("</svg>")
    return "\n".join(out) + "\n"


def _xml(text):
    return (str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            .replace('"', "&quot;"))


def measurements_template(specimens, profile_name, layers, gcode_names=("calibration.gcode",)):
    """CSV text to fill in after the bath, with instructions as ``#`` comments."""
    n_th = len({s.thickness_mm for s in specimens})
    head = [
        "# hostd calibration measurements for profile %s" % profile_name,
        "# %d rectangles: %d thickness values x %d repeats, %g x %g mm, %d layers."
        % (len(specimens), n_th, max(s.repeat for s in specimens), specimens[0].length_mm,
           specimens[0].width_mm, layers),
        "# 1. Print %s; calibration_layout.svg shows which rectangle is which" % " then ".join(
            gcode_names) +
        " specimen (the G-code names each one in a ;SPECIMEN: comment too).",
        "# 2. Take the rectangles off the bed and put them in a hot-water bath at 80-90 C until"
        " they stop shrinking (about a minute); let them cool flat.",
        "# 3. Measure each rectangle's length ALONG THE PRINTED PATHS (the %g mm side) in mm"
        " and write it in measured_length_mm. Leave nothing empty; delete the row of a"
        " specimen that failed." % specimens[0].length_mm,
        "# 4. hostd calibrate fit measurements.csv --profile %s -o %s-calibrated.yaml"
        % (profile_name, profile_name),
    ]
    return csv_text(head, COLUMNS, [[s.id, "%g" % s.thickness_mm, s.repeat, "%g" % s.length_mm,
                                     ""] for s in specimens])


def csv_text(comments, columns, rows):
    """A measurements file: ``#`` instruction lines, the header, one row per specimen."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    w.writerows(rows)
    return "\n".join(comments) + "\n" + buf.getvalue()


# ------------------------------------------------------------------------ fit

@dataclass
class Measurement:
    specimen: str
    thickness_mm: float
    repeat: str
    printed_length_mm: float
    measured_length_mm: float
    line: int

    @property
    def shrink(self):
        return max(1.0 - self.measured_length_mm / self.printed_length_mm, 0.0)


def read_measurements(text, source=None):
    """Parse a filled-in measurements CSV: list of :class:`Measurement`.

    ``#`` lines and blank lines are skipped. Raises :class:`CalibrationError`
    naming the file line for missing columns or values, non-numbers,
    non-positive values and growth (measured longer than printed).
    """
    lines = text.splitlines()
    body = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not body:
        raise CalibrationError("no measurements found", code="calibration.empty", file=source,
                               fix="fill in the CSV written by `hostd calibrate print`")
    header_line, header = body[0]
    cols = [c.strip() for c in next(csv.reader([header]))]
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise CalibrationError("missing column %r" % missing[0], code="calibration.columns",
                               file=source, where="line %d" % header_line,
                               fix="keep the header line: " + ",".join(COLUMNS))
    idx = {c: cols.index(c) for c in COLUMNS}
    out = []
    for no, ln in body[1:]:
        cells = [c.strip() for c in next(csv.reader([ln]))]
        where = "line %d" % no
        spec = cells[idx["specimen"]] if idx["specimen"] < len(cells) else "?"
        row = {}
        for c in COLUMNS[1:]:
            i = idx[c]
            v = cells[i] if i < len(cells) else ""
            label = "specimen %s: %s" % (spec, c)
            if c == "repeat":
                row[c] = v
                continue
            if v == "":
                raise CalibrationError(
                    "%s is empty" % label, code="calibration.missing_value", file=source,
                    where=where, fix="measure it, or delete the row to leave the specimen out")
            try:
                x = float(v)
            except ValueError:
                raise CalibrationError("%s is not a number: %r" % (label, v),
                                       code="calibration.not_a_number", file=source,
                                       where=where, fix="write a plain number in mm, e.g. 48.7")
            if not np.isfinite(x) or x <= 0:
                raise CalibrationError("%s must be a positive length, got %r" % (label, v),
                                       code="calibration.not_positive", file=source,
                                       where=where, fix="write the length in mm")
            row[c] = x
        m = Measurement(spec, row["thickness_mm"], row["repeat"], row["printed_length_mm"],
                        row["measured_length_mm"], no)
        if m.measured_length_mm > m.printed_length_mm * (1 + GROWTH_TOLERANCE):
            raise CalibrationError(
                "specimen %s grew: measured %g mm > printed %g mm; PLA paths only shrink when "
                "heated" % (spec, m.measured_length_mm, m.printed_length_mm),
                code="calibration.growth", file=source, where=where,
                fix="re-measure along the printed paths (the %g mm side), or check the row "
                    "belongs to this specimen" % m.printed_length_mm)
        out.append(m)
    if not out:
        raise CalibrationError("no measurements found", code="calibration.empty", file=source,
                               fix="fill in measured_length_mm for each specimen")
    return out


@dataclass
class CalibrationFit:
    """A fitted shrink curve and how well it fits the measurements."""

    curve: ShrinkCurve
    thickness_mm: np.ndarray  # (k,) distinct thicknesses
    mean_shrink: np.ndarray   # (k,) mean shrink per thickness
    residuals: np.ndarray     # (n,) measured shrink - fitted, per measurement
    rms: float
    shrink_range: tuple       # usable (min, max) shrink over theta_range_mm
    theta_range_mm: tuple


def fit_measurements(measurements, degree=4, theta_range_mm=None, source=None,
                     max_repeat_spread=MAX_REPEAT_SPREAD,
                     monotonic_tolerance=MONOTONIC_TOLERANCE):
    """Fit shrink(thickness) to measurements (per-thickness means).

    ``theta_range_mm`` (default: the measured span) is intersected with the
    measured span: the polynomial is not trusted beyond it. Raises
    :class:`CalibrationError` naming rows for too few thicknesses, repeats that
    disagree by more than ``max_repeat_spread``, shrink that rises with
    thickness by more than ``monotonic_tolerance``, or a fit that is not
    monotonic on the range.
    """
    t = np.array([m.thickness_mm for m in measurements])
    s = np.array([m.shrink for m in measurements])
    lines = np.array([m.line for m in measurements])
    uniq, inv = np.unique(np.round(t, 6), return_inverse=True)
    if len(uniq) < degree + 1:
        raise CalibrationError(
            "%d distinct thickness values are too few for a degree-%d fit (need %d)"
            % (len(uniq), degree, degree + 1), code="calibration.too_few", file=source,
            fix="measure more thickness values, or use --degree %d" % max(len(uniq) - 1, 1))
    mean = np.bincount(inv, weights=s) / np.bincount(inv)
    for k in range(len(uniq)):
        grp = np.flatnonzero(inv == k)
        if np.ptp(s[grp]) > max_repeat_spread:
            lo, hi = grp[np.argmin(s[grp])], grp[np.argmax(s[grp])]
            raise CalibrationError(
                "repeats at %g mm disagree: shrink %.1f %% (line %d) vs %.1f %% (line %d)"
                % (uniq[k], 100 * s[lo], lines[lo], 100 * s[hi], lines[hi]),
                code="calibration.repeats_disagree", file=source,
                where="lines %d and %d" % (lines[lo], lines[hi]),
                fix="re-measure both, or delete the row of a failed print")
    rise = np.diff(mean)
    bad = np.flatnonzero(rise > monotonic_tolerance)
    if bad.size:
        k = int(bad[0])
        rows = lambda j: ", ".join(str(x) for x in lines[inv == j])  # noqa: E731
        raise CalibrationError(
            "shrink rises with thickness: %.1f %% at %g mm (lines %s) but %.1f %% at %g mm "
            "(lines %s); thinner layers must shrink more"
            % (100 * mean[k], uniq[k], rows(k), 100 * mean[k + 1], uniq[k + 1], rows(k + 1)),
            code="calibration.not_monotonic", file=source, where="lines %s" % rows(k + 1),
            fix="re-measure those specimens (along the paths), or check the thickness column")
    lo, hi = uniq[0], uniq[-1]
    if theta_range_mm is not None:
        lo, hi = max(lo, theta_range_mm[0]), min(hi, theta_range_mm[1])
    # Thick layers shrink ~0 and the polynomial may dip just below zero there;
    # thicker than where shrink reaches zero is of no use, so stop the range there.
    grid = np.linspace(lo, hi, 4001)
    fitted = np.polyval(np.polyfit(uniq, mean, degree), grid)
    if fitted[0] > 0 and np.any(fitted < 1e-6):
        hi = float(grid[np.argmax(fitted < 1e-6) - 1])
    try:
        curve = ShrinkCurve(uniq, mean, degree=degree, theta_range_mm=(lo, hi), source=source)
    except InvalidProfile as exc:
        code = {"profile.shrink_not_monotonic": "calibration.not_monotonic"}.get(
            exc.code, "calibration.fit")
        raise CalibrationError("the degree-%d fit fails: %s" % (degree, exc.message), code=code,
                               file=source, where=exc.where,
                               fix="use a lower --degree, or re-measure the outliers") from None
    res = s - curve.sigma(t)
    return CalibrationFit(curve=curve, thickness_mm=uniq, mean_shrink=mean, residuals=res,
                          rms=float(np.sqrt(np.mean(res ** 2))), shrink_range=curve.sigma_range,
                          theta_range_mm=(float(lo), float(hi)))
