"""The plan's fit step: when the free method fits the relief, which lever it applies
(:mod:`pipeline.layout.fit` searches for them), and the warnings that say so.

``fitted`` makes the relief form when nobody asked for a height; ``refuse_too_high``
refuses a height asked for that does not form, with the sidecar line that would;
``take_hold`` plans again, smoothed as much as the sheet needs to hold its shape, a
plan whose fit laid out but whose sheet did not hold it.
"""

import time
from pathlib import Path

import numpy as np

from pipeline.input.simplify import simplify
from pipeline.layout import keep, local
from pipeline.layout.fit import fit_height, scaled
from pipeline.layout.fit import program_relief as fit_relief
from pipeline.layout.reach import reach
from pipeline.problems import INVALID_AREA_WARN


def height_asked(sidecar):
    return sidecar is not None and (sidecar.height_mm is not None
                                     or sidecar.height_scale is not None)


def fitted(result, hf, profile, sidecar, opts, stage, timing, force=False):
    """Make the relief form when nobody asked for a height (it came from the profile's
    defaults or the file's own units) and the sidecar allows it: smoothed where that
    forms the relief as given (``fit: auto``), else lowered."""
    mode = (sidecar.fit if sidecar is not None else None) or "auto"
    if not force and (mode == "off" or height_asked(sidecar)):
        return hf
    t = stage("fit", "how high the sheet can rise")
    result.fit = _fit(result, hf, profile, opts, smooth_first=mode != "relief")
    timing["fit"] = time.perf_counter() - t
    fit = result.fit
    fit.keep = keep.of_fit(fit, _size_mm(result.validated), profile.layers)
    to_keep = keep.sentence(fit.keep)
    to_keep = "; " + to_keep if to_keep else ""
    if fit.applied_smooth_mm is not None:
        smoothed = fit.smoothed
        _removed(fit, hf, smoothed)
        if fit.local is None:
            # The looks that follow (the hold) start from the smoothing applied.
            opts["smooth_mm"] = fit.applied_smooth_mm
        how = ("smoothed %g mm" % fit.applied_smooth_mm if fit.local is None else
               "smoothed where the sheet cannot form it (up to %g mm, %.0f %% of the sheet "
               "moved more than 0.1 mm; as given elsewhere)" % (
                   fit.applied_smooth_mm, 100 * fit.local["moved_share"]))
        result.problems.append({
            "code": "fit.smoothed",
            "message": "%s, keeping the relief (%.1f mm): %s; the smoothing "
                       "moves the surface by %.2f mm on average (9 in 10 points by at most "
                       "%.2f mm)%s" % (how, fit.max_height_mm, fit.reason, fit.removed_mm,
                                       fit.removed_p90_mm, to_keep),
            "fix": "nothing to do; to keep the narrow features write `fit: relief` in the "
                   "sidecar (the relief is lowered instead, and the sheet misses them) or "
                   "`fit: off`"})
        return smoothed
    if fit.applied_scale < 1.0:
        result.problems.append({
            "code": "fit.lowered",
            "message": "the relief was lowered from %.1f to %.1f mm (%.0f %%): %s%s" % (
                fit.requested_height_mm, fit.max_height_mm, 100 * fit.applied_scale,
                fit.reason, to_keep),
            "fix": "nothing to do; to plan the full relief anyway write `fit: off` in the "
                   "sidecar, or ask for a height there (%s)%s" % (
                       fit.sidecar_line(), fit.smoothing_advice())})
        lowered = scaled(hf, fit.applied_scale)
        _removed(fit, hf, lowered)
        return lowered
    return hf


def refuse_too_high(result, hf, profile, sidecar, opts, timing):
    """A relief the sidecar asked for that does not form is refused, with the sidecar
    line that would make it form."""
    if not (height_asked(sidecar) and result.flat.invalid_area_fraction > INVALID_AREA_WARN):
        return
    t = time.perf_counter()
    result.fit = _fit(result, hf, profile, opts)
    result.fit.applied_scale = 1.0
    result.fit.reason = "asked for in the sidecar; " + result.fit.reason
    timing["fit"] = time.perf_counter() - t
    result.problems.append({
        "code": "fit.too_high",
        "message": "the relief asked for (%s) does not form: %.1f %% of the sheet "
                   "needs more than the material can do; at most %.1f mm forms" % (
                       _asked(result.fit), 100 * result.flat.invalid_area_fraction,
                       result.fit.max_height_mm),
        "fix": _too_high_fix(result.fit, Path(sidecar.source).name if sidecar.source else "")})


def _too_high_fix(fit, sidecar_name):
    """The sidecar lines that form a relief asked for: the smoothing that keeps the
    height first, where one does (it changes the input least), then the lower height."""
    where = "in the sidecar %s" % sidecar_name
    if fit.min_smooth_mm is not None:
        return ("write `smooth_mm: %g` %s to keep the height (narrower features smoothed "
                "away) or `%s` (the relief lowered to what forms), or remove the height to "
                "let hostd fit it" % (fit.min_smooth_mm, where, fit.sidecar_line()))
    return "write `%s` %s (or remove its height to let hostd fit it)" % (fit.sidecar_line(),
                                                                           where)


def _asked(fit):
    """The relief asked for, and what smoothing left of it where that differs."""
    asked, planned = fit.requested_sidecar_mm(), fit.requested_height_mm
    if abs(asked - planned) < 0.05:
        return "%.1f mm" % planned
    return "%.1f mm; %.1f mm once smoothed" % (asked, planned)


def _fit(result, hf, profile, opts, smooth_first=False):
    """The fit of ``hf``, both levers: the relief, and the smoothing of the input as
    validated (``result.validated``) that would form it at full height, within the
    stack's curvature reach; ``smooth_first`` applies the smoothing where one forms."""
    lim = profile.shrink_limits
    fit = fit_height(hf, lim.s_min, lim.s_max, opts["smooth_mm"],
                     fine_mm=profile.mesh.grid_mm,
                     fine_iterations=profile.flatten.free_iterations,
                     resmooth=_resmooth(result, hf, opts, profile),
                     reach_of=lambda field, mesh, flat: reach(field, mesh, flat, profile),
                     smooth_first=smooth_first)
    if profile.flatten.fit_smoothing == "local" and fit.applied_smooth_mm is not None:
        fit.local = {"blend_mm": local.BLEND_MM}
    # A sidecar's height_mm sets the input's highest point, before the smoothing that
    # lowers the peaks: its line must ask for more than the relief that forms.
    top = float(np.nanmax(result.input_hf.z))
    if fit.requested_height_mm > 0 and top > 0:
        fit.sidecar_per_mm = top / fit.requested_height_mm
    return fit


def _resmooth(result, hf, opts, profile):
    """The second lever at ``smooth_mm``: the input as validated smoothed that much
    instead of the sidecar's amount (``flatten.fit_smoothing: global``), or ``hf``
    smoothed up to that much only where the sheet cannot form it (``local``,
    :mod:`pipeline.layout.local`)."""
    if profile.flatten.fit_smoothing == "local":
        fits = {}

        def at(smooth_mm):
            if "fit" not in fits:
                fits["fit"] = local.LocalFit(hf, *local.limits(profile),
                                             measure_mm=profile.mesh.grid_mm)
            return fits["fit"].at(smooth_mm)
        return at
    return lambda smooth_mm: simplify(result.validated, opts["min_prominence_mm"],
                                      smooth_mm)[0]


def _removed(fit, hf, fitted_hf):
    """What the lever applied removed from ``hf``: the map (``fit.removed_map``, mm), its
    mean and 90th percentile, and for a local smoothing the share moved at all."""
    fit.removed_map = local.removed(hf, fitted_hf)
    inside = fit.removed_map[np.isfinite(fit.removed_map)]
    fit.removed_mm = float(inside.mean())
    fit.removed_p90_mm = float(np.percentile(inside, 90))
    if fit.applied_smooth_mm is not None and isinstance(fit.local, dict):
        fit.local["moved_share"] = round(float((inside > 0.1).mean()), 4)


def program_relief(result, opts, profile, held_smooth_mm=None):
    """Where the plan chose to smooth the relief (the fit's global smoothing, or the
    smoothing that holds, ``held_smooth_mm``), the relief its curvature program reads:
    the input as validated smoothed only ``curvature.program_smoothing`` as much, lowered
    as the fit lowered it. None where the plan smoothed nothing of its own or the
    profile asks for the target itself (:func:`pipeline.layout.fit.program_share`).

    The smoothing takes out the slopes and the excess length the layout cannot lay out;
    the finer relief's curvature still programs the sheet closer to the file (half the
    fit's smoothing, the tiles dropped without a height at their native size: the
    Vancouver tile 2.46 mm from the file instead of 2.85, the coast tile 5.15 instead of
    5.54, the 175 mm rough terrain 1.60 instead of 1.88; each as printable, and 0.19 %,
    0.46 % and 0.58 % of its diameter from its target instead of 0.59 %, 0.49 % and
    0.71 %)."""
    fit, smooth = result.fit, held_smooth_mm
    if fit is not None and fit.local is None and fit.applied_smooth_mm is not None:
        smooth = fit.applied_smooth_mm
    if smooth is None:
        return None
    scale = 1.0 if fit is None or fit.applied_scale is None else fit.applied_scale
    return fit_relief(result.validated, opts["min_prominence_mm"], smooth, profile, scale)


def take_hold(result, sidecar, plan_again):
    """Where nobody asked for a height and the fit may smooth (``fit: auto``), a plan
    whose sheet ended too far from the shape is planned again with the smoothing at which
    the report's ``hold`` found that it holds, and says so: the fit lays the relief out
    and keeps it within reach on a quick mesh, the hold simulates the sheet, so it can
    ask for more. Returns the plan made again (printable or not, with the first plan's
    ``hold`` and figures in ``fit.held``), or None where nothing was taken.

    plan_again : callable(smooth_mm) -> Plan."""
    hold = result.report.get("hold") or {}
    mode = (sidecar.fit if sidecar is not None else None) or "auto"
    if (hold.get("smooth_mm") is None or mode != "auto" or height_asked(sidecar)
            or result.blocked or result.profile.flatten.method != "free"):
        return None
    first = result.report
    held = plan_again(hold["smooth_mm"])
    was = first["fit"]["applied_smooth_mm"] or first["fit"]["smooth_mm"]
    got = held.report["simulation"]["mean_displacement_fraction"]
    held.problems.insert(0, {
        "code": "fit.held",
        "message": "smoothed %g mm instead of %g mm: at %g mm the simulated sheet ended %.1f %% "
                   "of its diameter from the shape (the profile allows %.1f %%), smoothed it "
                   "ends %.1f %%; narrower features do not form in this sheet" % (
                       hold["smooth_mm"], was, was,
                       100 * first["simulation"]["mean_displacement_fraction"],
                       100 * hold["limit"], 100 * got),
        "fix": "nothing to do; to plan it smoothed less write `fit: relief` in the sidecar "
               "(the relief is lowered instead) or `smooth_mm: ...` with the smoothing you "
               "want"})
    held.report["hold"] = hold
    if held.report.get("fit") is not None:
        held.report["fit"]["held"] = {
            "smooth_mm": hold["smooth_mm"], "first_smooth_mm": was,
            "first_mean_displacement_fraction": first["simulation"]["mean_displacement_fraction"],
            "first_fidelity": first.get("fidelity")}
    held.report["warnings"] = list(held.problems)
    return held


def _size_mm(hf):
    """The footprint's longest side (mm), as the sidecar's ``size_mm`` means it."""
    inside = np.isfinite(hf.z)
    rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
    return float(max(rows[-1] - rows[0], cols[-1] - cols[0]) * hf.pixel_mm)
