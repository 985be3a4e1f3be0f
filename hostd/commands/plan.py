"""`hostd plan INPUT --profile NAME_OR_PATH -o OUTDIR`: plan one file, write its outputs."""

import sys
import time
from pathlib import Path

from pipeline.errors import MeshingError, PipelineError
from pipeline.profiles.profile import load_profile


def add_parser(sub):
    p = sub.add_parser("plan", help="plan one height field into flat layout, pictures and report",
                       description="Run the flatten-and-plan pipeline on INPUT and write "
                                   "into OUTDIR: %s (with a coloured input also %s); on an "
                                   "error only NAME.error.json (nothing when INPUT is "
                                   "missing)." % (
                                       ", ".join(_outputs(False)),
                                       ", ".join(sorted(set(_outputs(True))
                                                        - set(_outputs(False))))))
    p.add_argument("input", help="height field: PNG/TIFF, .npy/.npz (mm) or STL/OBJ/PLY/GLB")
    p.add_argument("--profile", "-p", default=None,
                   help="printer profile name or YAML path (default: the sidecar's, "
                        "else generic-0.5mm)")
    p.add_argument("-o", "--outdir", default=".", help="output folder (default: .)")
    p.add_argument("--method", choices=("isoline", "free"), default=None,
                   help="layout method (default: the sidecar's method, else the profile's "
                        "flatten.method): isoline, the paper's, or free, a print direction "
                        "per triangle")
    p.add_argument("--fit", action="store_true",
                   help="with the free method: fit the relief to what the material can form "
                        "(even where the sidecar asks for a height) and print the scales tried")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress on stderr")
    p.set_defaults(func=run)


def _outputs(color):
    from hostd.outputs import output_names
    return list(output_names("NAME", color=color).values())


def _profile_name(args):
    if args.profile:
        return args.profile
    from pipeline.input.sidecar import load_sidecar, sidecar_path
    try:
        side = load_sidecar(sidecar_path(Path(args.input)))
        if side is not None and getattr(side, "profile", None):
            return side.profile
    except PipelineError:
        pass  # the pipeline reports the sidecar error properly when it reads it
    return "generic-0.5mm"


def _method(args):
    """The layout method the command asks for (over the sidecar's and the profile's)."""
    return "free" if args.fit and not args.method else args.method


def _print_fit(fit):
    given = fit.get("reach_given")
    print("relief scale  invalid area  flipped  reach p90")
    for scale, area, flipped in fit["tried"]:
        print("%12.3f  %11.2f %%  %7d  %s" % (scale, 100 * area, flipped, _reach_cell(
            given["p90"] if given and scale == 1.0 else None)))
    if fit.get("smooth_tried"):
        reach = dict(fit.get("smooth_reach", []))
        print("   smooth_mm  invalid area  flipped  reach p90   (the relief as given)")
        for smooth, area, flipped in fit["smooth_tried"]:
            print("%12g  %11.2f %%  %7d  %s" % (smooth, 100 * area, flipped,
                                                _reach_cell(reach.get(smooth))))
    print("fitted: %.1f mm of %.1f mm (scale %.3f), %d solves in %.1f s (%.1f s of them "
          "smoothing): %s" % (
              fit["max_height_mm"], fit["requested_height_mm"], fit["applied_scale"],
              fit["solves"] + len(fit.get("smooth_tried", [])), fit["seconds"],
              fit.get("smooth_seconds", 0.0), fit["reason"]))
    if fit.get("smooth_tried"):
        print("the relief as given forms with smooth_mm: %g" % fit["min_smooth_mm"]
              if fit["min_smooth_mm"] is not None else
              "no smoothing up to %g mm forms the relief as given" % fit["smooth_tried"][-1][0])
    if fit.get("applied_smooth_mm") is not None:
        print("applied: smooth_mm %g at the relief as given; it moves the surface by %.2f mm "
              "on average" % (fit["applied_smooth_mm"], fit.get("removed_mm") or 0.0))
    if given:
        from pipeline.layout.reach import WITHIN
        print("reach of the relief as given: its curvature is %.2f of the most the layers "
              "can curl (p90; %s)" % (given["p90"], "within reach" if given["within"] else
                                      "above %g: its narrow features do not form" % WITHIN))


def _reach_cell(p90):
    """A reach p90 for the fit's table: '-' where the solve did not ask."""
    return "%9s" % ("-" if p90 is None else "%.2f" % p90)


def run(args):
    from hostd import planner

    show = not args.quiet and sys.stderr.isatty()
    t0 = time.perf_counter()

    def progress(stage, message):
        if show:
            print("[%6.1fs] %-9s %s" % (time.perf_counter() - t0, stage, message),
                  file=sys.stderr, flush=True)

    name = Path(args.input).stem
    if not Path(args.input).is_file():
        # Nothing was planned: no NAME.error.json beside wherever the command ran.
        what = "a folder, not a file" if Path(args.input).is_dir() else "input file not found"
        print("hostd plan: error heightfield.not_found: %s: %s. Fix: give the path of a "
              "height field (PNG/TIFF, .npy/.npz, STL/OBJ/PLY/GLB)" % (args.input, what),
              file=sys.stderr)
        return 2
    try:
        profile = load_profile(_profile_name(args))
        plan = planner.run(args.input, profile, args.outdir, progress=progress,
                           force_fit=args.fit, method=_method(args))
    except PipelineError as exc:
        print("hostd plan: error %s: %s" % (exc.code, exc.text()), file=sys.stderr)
        if exc.code.startswith("profile."):
            return 3
        if isinstance(exc, MeshingError):
            # The isoline mesher failing on a valid field is hostd's fault, not the file's.
            print("hostd plan: this is a fault of hostd's isoline mesher, not of the file: "
                  "plan it with --method free (no isoline mesh), and please report it",
                  file=sys.stderr)
            return 5
        print("hostd plan: wrote %s" % (Path(args.outdir) / (name + ".error.json")),
              file=sys.stderr)
        return 2
    r = plan.report
    if args.fit and "fit" in r:
        _print_fit(r["fit"])
    for w in r.get("warnings", []):
        print("hostd plan: warning %s: %s. Fix: %s" % (w["code"], w["message"], w["fix"]),
              file=sys.stderr)
    print("%s: %d triangles, invalid edges %.1f %%, simulated mean displacement %.2f mm "
          "(max %.2f), %.1f s -> %s" % (
              r["input"], r["mesh"]["triangles"], 100 * r["flatten"]["invalid_edge_fraction"],
              r["simulation"]["mean_displacement_mm"], r["simulation"]["max_displacement_mm"],
              r["timing_s"]["total"], Path(args.outdir) / (name + ".report.json")))
    if r.get("needs_decision"):
        print("hostd plan: planned, but outside the profile's printable limits (see the "
              "warnings above): the daemon holds such a job until a person approves it "
              "(`hostd approve ID` or \"Print anyway\" on the page)", file=sys.stderr)
        return 4
    if not r["printable"]:
        print("hostd plan: planned, but NOT printable (see the warnings above)", file=sys.stderr)
        return 4
    return 0
