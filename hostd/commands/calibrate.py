"""``hostd calibrate``: measure your printer's shrink curve (paper section 6, Fig. 2).

``hostd calibrate print --profile P -o DIR`` writes the G-code for rectangles of
parallel paths at evenly spaced layer thicknesses, a layout SVG naming each one
and a CSV to fill in after the hot-water bath; ``hostd calibrate fit
MEASURED.csv --profile P -o NEW.yaml`` fits the measurements and writes an
updated copy of the profile (never the original).

``bilayer`` / ``bilayer-fit`` and ``across`` / ``across-fit`` do the same for the
curvature program's constants: strips that curl, their rise over a chord measured with
a ruler (:mod:`pipeline.profiles.bilayer`, :mod:`pipeline.profiles.across`).
"""

import datetime
import os
import sys
from pathlib import Path

import numpy as np

from pipeline import __version__
from pipeline.profiles import across, bilayer
from pipeline.profiles.calibration import (COLUMNS, CalibrationError, calibration_traces, fit_measurements,
                                  layout_plates, layout_svg, measurements_template,
                                  read_measurements, thickness_values)
from pipeline.errors import PipelineError
from pipeline.gcode.writer import GcodeSettings, write_thickness_gcode
from pipeline.profiles.profile import load_profile
from pipeline.profiles.dump import profile_to_yaml

PROG = "hostd calibrate"


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "calibrate", help="print calibration rectangles and fit the measured shrink curve",
        description=__doc__.split("\n\n")[1].replace("\n", " ").replace("``", "\""))
    sub = parser.add_subparsers(dest="calibrate_step", metavar="STEP")
    p = sub.add_parser("print", help="write calibration G-code, layout SVG and a CSV template",
                       description="Write DIR/calibration.gcode (or one file per plate when "
                                   "the bed is too small for all rectangles), "
                                   "DIR/calibration_layout.svg and DIR/measurements.csv.")
    _common(p, "measurements.csv")
    p.add_argument("--values", type=int, default=11,
                   help="thickness values evenly across the profile's range (default 11)")
    p.add_argument("--repeats", type=int, default=3, help="rectangles per value (default 3)")
    p.add_argument("--plates", type=int, default=None,
                   help="bed loads to spread them over (default: as few as fit)")
    p.add_argument("--gap-mm", type=float, default=3.0, help="gap between rectangles (3 mm)")
    p.set_defaults(func=run_print)
    f = sub.add_parser("fit", help="fit measured lengths and write an updated profile",
                       description="Fit the shrink curve to a filled-in measurements CSV, print "
                                   "the residuals and the usable shrink range, and write an "
                                   "updated copy of the profile.")
    f.add_argument("measured", metavar="MEASURED.csv")
    _common(f)
    f.add_argument("--degree", type=int, default=4, help="polynomial degree (paper: 4)")
    f.set_defaults(func=run_fit)
    _strip_steps(sub, "bilayer", "bilayer strips",
                 "strips whose lower layers are thinner than their upper ones by a few "
                 "differences (one with none)", run_bilayer,
                 "the bilayer constant", "c of kappa = c (sigma_bottom - sigma_top) / h",
                 "curvature.bilayer_c", run_bilayer_fit)
    _strip_steps(sub, "across", "strips of the layers across the paths",
                 "strips whose second and second-last layers print along them, thinner and "
                 "thicker by a few differences (one with none), and every other layer across "
                 "them", run_across,
                 "the constant of the layers across",
                 "c_across of kappa = c_across * 4 (N - 3) / N^2 * (sigma_2 - sigma_N-1) / h",
                 "curvature.across_c", run_across_fit)
    parser.set_defaults(func=lambda args: _usage(parser))
    return parser


def _strip_steps(sub, kind, what, strips, run, constant, formula, key, run_fit):
    """The two steps of a strip calibration: ``KIND`` writes the strips' G-code, layout
    and CSV; ``KIND-fit`` fits ``formula`` to the measured CSV into profile ``key``."""
    p = sub.add_parser(kind, help="write G-code for %s and a CSV template" % what,
                       description="Write DIR/%s.gcode: %s; DIR/%s_layout.svg and DIR/%s.csv."
                                   % (kind, strips, kind, kind))
    _common(p, "%s.csv" % kind)
    p.add_argument("--values", type=int, default=5, help="thickness differences (default 5)")
    p.add_argument("--repeats", type=int, default=2, help="strips per difference (default 2)")
    p.set_defaults(func=run)
    f = sub.add_parser("%s-fit" % kind, help="fit %s from measured strips" % constant,
                       description="Fit %s to the measured curl of the strips and write an "
                                   "updated copy of the profile with it (%s)." % (formula, key))
    f.add_argument("measured", metavar="%s.csv" % kind.upper())
    _common(f)
    f.set_defaults(func=run_fit)


def _common(p, csv_name=None):
    """--profile, -o and --force: a step that writes a folder (with ``csv_name`` to fill
    in) or, without one, a step that writes a new profile."""
    p.add_argument("--profile", required=True, help="profile name or path to a .yaml file")
    if csv_name:
        p.add_argument("-o", "--out", required=True, metavar="DIR", help="output directory")
        p.add_argument("--force", action="store_true",
                       help="overwrite a %s that already has measurements" % csv_name)
    else:
        p.add_argument("-o", "--out", required=True, metavar="NEW.yaml",
                       help="where to write the updated profile (never the original)")
        p.add_argument("--force", action="store_true", help="overwrite NEW.yaml if it exists")


def _usage(parser):
    parser.print_help(sys.stderr)
    return 2


def _fail(exc):
    print("%s: error [%s]: %s" % (PROG, exc.code, exc.text()), file=sys.stderr)
    return 1


def _write_atomic(path, text):
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _has_measurements(csv_path):
    try:
        rows = read_measurements(csv_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, PipelineError):
        # Partly filled: any non-empty measured cell counts.
        try:
            lines = csv_path.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError):
            return True
        body = [ln for ln in lines if ln.strip() and not ln.startswith("#")]
        return any(ln.rsplit(",", 1)[-1].strip() for ln in body[1:])
    return bool(rows)


def run_print(args):
    try:
        profile = load_profile(args.profile)
        out = Path(args.out)
        csv_path = out / "measurements.csv"
        if csv_path.exists() and not args.force and _has_measurements(csv_path):
            raise CalibrationError(
                "%s already holds measurements" % csv_path, code="calibration.would_overwrite",
                file=csv_path, fix="use another -o DIR, or --force to start over")
        th = thickness_values(profile.thickness_mm.min, profile.thickness_mm.max, args.values)
        plates = layout_plates(th, args.repeats, profile.bed_mm, plates=args.plates,
                               gap_mm=args.gap_mm)
        settings = GcodeSettings.from_profile(profile, arc_tolerance_mm=0.0)
        out.mkdir(parents=True, exist_ok=True)
        names = (["calibration.gcode"] if len(plates) == 1 else
                 ["calibration-plate%d.gcode" % (i + 1) for i in range(len(plates))])
        total_s, total_g = 0.0, 0.0
        for i, (plate, name) in enumerate(zip(plates, names)):
            traces, thetas, labels = calibration_traces(plate, profile.path_width_mm)
            stats = write_thickness_gcode(
                traces, thetas, settings, out / name, labels=labels, center=False,
                name="calibration plate %d of %d, profile %s" % (i + 1, len(plates), profile.name),
                header_extra=["calibration: %d rectangles %g x %g mm, thickness %g..%g mm, "
                              "specimens %d..%d" % (len(plate), plate[0].length_mm,
                                                    plate[0].width_mm, th.min(), th.max(),
                                                    plate[0].id, plate[-1].id)])
            total_s += stats["estimated_print_s"]
            total_g += stats["filament_g"]
        specimens = [s for plate in plates for s in plate]
        title = "hostd calibration, profile %s: %d rectangles, thickness %g..%g mm" % (
            profile.name, len(specimens), th.min(), th.max())
        _write_atomic(out / "calibration_layout.svg", layout_svg(plates, profile.bed_mm, title))
        _write_atomic(csv_path, measurements_template(specimens, profile.name, profile.layers,
                                                          names))
    except PipelineError as exc:
        return _fail(exc)
    print("%d rectangles (%d thickness values %s mm x %d repeats) on %d plate(s)"
          % (len(specimens), len(th), ", ".join("%g" % t for t in th), args.repeats,
             len(plates)))
    print("estimated %.0f min, %.1f g of filament" % (total_s / 60, total_g))
    for name in names + ["calibration_layout.svg", "measurements.csv"]:
        print("wrote %s" % (out / name))
    print("next: print, bathe at 80-90 C, measure along the paths, fill in %s, then\n"
          "  hostd calibrate fit %s --profile %s -o %s-calibrated.yaml"
          % (csv_path, csv_path, args.profile, profile.name))
    return 0


def _same_file(a, b):
    try:
        return Path(a).resolve() == Path(b).resolve() or (
            Path(a).exists() and Path(b).exists() and os.path.samefile(a, b))
    except OSError:
        return False


def _new_profile_path(profile, args):
    """Where a calibrated copy goes: never the original, never over a file unasked."""
    new = Path(args.out)
    if profile.source and _same_file(new, profile.source):
        raise CalibrationError(
            "refusing to overwrite the original profile %s" % profile.source,
            code="calibration.would_overwrite_profile", file=new,
            fix="write the calibrated profile to a new file, e.g. %s-calibrated.yaml"
                % profile.name)
    if new.exists() and not args.force:
        raise CalibrationError("%s already exists" % new, code="calibration.would_overwrite",
                               file=new, fix="choose another -o path, or add --force")
    return new


def _read_text(src):
    try:
        return Path(src).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError("cannot read measurements: %s" % exc,
                               code="calibration.unreadable", file=src,
                               fix="give the CSV `hostd calibrate` wrote") from None


def run_fit(args):
    try:
        profile = load_profile(args.profile)
        new = _new_profile_path(profile, args)
        if args.degree < 1:
            raise CalibrationError("--degree must be at least 1", code="calibration.degree")
        src = Path(args.measured)
        rows = read_measurements(_read_text(src), source=str(src))
        trange = (profile.thickness_mm.min, profile.thickness_mm.max)
        fit = fit_measurements(rows, degree=args.degree, theta_range_mm=trange, source=str(src))
        lo, hi = fit.theta_range_mm
        s_lo, s_hi = fit.shrink_range
        changes = {
            "name": new.stem if new.suffix in (".yaml", ".yml") else new.name,
            "shrink_curve": {"degree": args.degree,
                             "points": [[round(float(t), 4), round(float(s), 5)]
                                        for t, s in zip(fit.thickness_mm, fit.mean_shrink)]},
            "shrink_limits": {"s_min": round(max(s_lo, 0.0), 4), "s_max": round(s_hi, 4)},
            "thickness_mm": {"min": round(lo, 4), "max": round(hi, 4)},
        }
        comment = ("hostd printer profile calibrated by `hostd calibrate fit` (hostd %s) on %s\n"
                   "from %s (%d measurements, %d thickness values), starting from %s.\n"
                   "Degree-%d fit, RMS residual %.2f %% shrink; usable shrink %.1f..%.1f %%."
                   % (__version__, datetime.date.today().isoformat(), src.name, len(rows),
                      len(fit.thickness_mm), profile.source or profile.name, args.degree,
                      100 * fit.rms, 100 * s_lo, 100 * s_hi))
        text = profile_to_yaml(profile, comment=comment, **changes)
        _write_atomic(new, text)
    except PipelineError as exc:
        return _fail(exc)
    _report(rows, fit, trange, new)
    return 0


def _report(rows, fit, trange, new):
    print("%-9s %-10s %-7s %9s %9s %9s" % ("specimen", "thickness", "repeat", "shrink%",
                                           "fit%", "resid%"))
    fitted = fit.curve.sigma(np.array([r.thickness_mm for r in rows]))
    for r, f, res in zip(rows, fitted, fit.residuals):
        print("%-9s %-10g %-7s %9.2f %9.2f %+9.2f" % (r.specimen, r.thickness_mm, r.repeat,
                                                       100 * r.shrink, 100 * f, 100 * res))
    print("mean shrink per thickness: " + ", ".join(
        "%g mm %.1f%%" % (t, 100 * s) for t, s in zip(fit.thickness_mm, fit.mean_shrink)))
    print("fit: degree %d, RMS residual %.2f %% shrink (%d measurements)"
          % (fit.curve.degree, 100 * fit.rms, len(rows)))
    lo, hi = fit.theta_range_mm
    print("usable shrink range: %.1f..%.1f %% over thickness %g..%g mm"
          % (100 * fit.shrink_range[0], 100 * fit.shrink_range[1], lo, hi))
    if (lo, hi) != tuple(trange):
        print("note: thickness range narrowed from %g..%g mm to the measured %g..%g mm"
              % (trange[0], trange[1], lo, hi))
    print("wrote %s" % new)


def run_bilayer(args):
    return _run_strips(args, "bilayer")


def run_across(args):
    return _run_strips(args, "across")


def _run_strips(args, kind):
    """Write the ``kind`` (``bilayer`` or ``across``) strips' G-code, layout and CSV."""
    try:
        profile = load_profile(args.profile)
        out = Path(args.out)
        csv_path = out / (kind + ".csv")
        if csv_path.exists() and not args.force and any(
                s.chord_mm for s in _measured_or_none(csv_path)):
            raise CalibrationError(
                "%s already holds measurements" % csv_path, code="calibration.would_overwrite",
                file=csv_path, fix="use another -o DIR, or --force to start over")
        t_range = (profile.thickness_mm.min, profile.thickness_mm.max)
        cp, others, extra = profile.curvature, (), []
        if kind == "bilayer":
            pairs = bilayer.thickness_pairs(profile.shrink_curve, profile.layers, *t_range,
                                            args.values, c=cp.bilayer_c)
        else:
            pairs = across.thickness_pairs(profile.shrink_curve, profile.layers, *t_range,
                                           args.values, c=cp.across_constant)
        plates, pair_of = bilayer.strips(pairs, args.repeats, profile.bed_mm)
        specimens = [s for plate in plates for s in plate]
        if kind == "bilayer":
            traces, thetas, labels = bilayer.strip_traces(specimens, pair_of, profile.layers,
                                                          profile.path_width_mm)
            template = bilayer.template(specimens, pair_of, profile.name)
        else:
            middle = float(pairs[0][0])
            (traces, thetas, labels), along = across.strip_traces(
                specimens, pair_of, profile.layers, profile.path_width_mm, middle)
            two = across.layer_numbers(profile.layers)
            others = [(along[0], along[1], None, two, "across")]
            extra = ["across strips: layers %d and %d along the %g mm side (a plan's layers "
                     "across), the others across it at %g mm"
                     % (two[0], two[1], across.LENGTH_MM, middle)]
            template = across.template(specimens, pair_of, profile.name, profile.layers, middle)
        out.mkdir(parents=True, exist_ok=True)
        stats = write_thickness_gcode(
            traces, thetas, GcodeSettings.from_profile(profile, arc_tolerance_mm=0.0),
            out / (kind + ".gcode"), labels=labels, center=False, others=others,
            name="%s strips, profile %s" % (kind, profile.name), header_extra=extra)
        _write_atomic(out / (kind + "_layout.svg"), layout_svg(
            plates, profile.bed_mm, "hostd %s strips, profile %s" % (kind, profile.name)))
        _write_atomic(csv_path, template)
    except PipelineError as exc:
        return _fail(exc)
    print("%d strips (%s mm: %s) x %d repeats, estimated %.0f min"
          % (len(pairs), "bottom/top" if kind == "bilayer" else "layer %d/%d" % tuple(two),
             ", ".join("%g/%g" % tuple(p) for p in pairs), args.repeats,
             stats["estimated_print_s"] / 60))
    for name in (kind + ".gcode", kind + "_layout.svg", kind + ".csv"):
        print("wrote %s" % (out / name))
    print("next: print, bathe, measure each strip's rise over its chord into %s, then\n"
          "  hostd calibrate %s-fit %s --profile %s -o %s-%s.yaml"
          % (csv_path, kind, csv_path, args.profile, profile.name, kind))
    return 0


def _measured_or_none(csv_path):
    try:
        return bilayer.read_strips(csv_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, PipelineError):
        return [bilayer.Strip("?", 0, 0, 1.0, 0.0)]


def run_bilayer_fit(args):
    return _run_strips_fit(args, "bilayer")


def run_across_fit(args):
    return _run_strips_fit(args, "across")


def _run_strips_fit(args, kind):
    """Fit the constant of the ``kind`` strips and write the profile's copy with it."""
    what = {"bilayer": "bilayer constant c", "across": "constant of the layers across "
                                                       "c_across"}[kind]
    try:
        profile = load_profile(args.profile)
        new = _new_profile_path(profile, args)
        src = Path(args.measured)
        strips = bilayer.read_strips(_read_text(src), source=str(src), kind=kind)
        if kind == "bilayer":
            c, rms, pts = bilayer.fit_c(strips, profile.shrink_curve, profile.layers)
            section = {"bilayer_c": round(c, 4), "status": "measured"}
        else:
            c, rms, pts = across.fit_c(strips, profile.shrink_curve, profile.layers)
            section = {"across_c": round(c, 4), "across_status": "measured"}
        if not 0 < c <= 20:
            raise CalibrationError("the strips give c = %.3g, which no %s strip has" % (c, kind),
                                   code="calibration.bad_fit", file=src,
                                   fix="check that rise_mm is measured on the curled side and "
                                       "that each row names its strip's thicknesses")
        comment = ("hostd printer profile with the %s fitted by `hostd calibrate %s-fit` (hostd %s) "
                   "on %s\nfrom %s (%d strips), starting from %s."
                   % (what, kind, __version__, datetime.date.today().isoformat(), src.name,
                      len(strips), profile.source or profile.name))
        _write_atomic(new, profile_to_yaml(
            profile, comment=comment, name=new.stem if new.suffix in (".yaml", ".yml") else
            new.name, curvature=section))
    except PipelineError as exc:
        return _fail(exc)
    print("%-9s %9s %9s %12s %12s" % ("specimen", "bottom_mm", "top_mm", "curl 1/mm",
                                      "fit 1/mm"))
    for s, (x, k) in zip(strips, pts):
        print("%-9s %9g %9g %12.5f %12.5f" % (s.specimen, s.bottom_mm, s.top_mm, k, c * x))
    print("%s = %.3f (RMS residual %.5f 1/mm, %d strips)" % (what, c, rms, len(strips)))
    print("wrote %s" % new)
    return 0


__all__ = ["add_parser", "run_print", "run_fit", "run_bilayer", "run_bilayer_fit", "run_across",
           "run_across_fit", "COLUMNS"]
