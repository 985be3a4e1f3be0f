"""The job card's words on the shape: how far the simulated sheet ends from the file as
dropped (the report's ``fidelity``) and from the target it planned (the printability
gate's figure), each in a sentence, so that neither is read for the other."""


def _pct(v):
    return "%.0f %%" % (100 * v)


def shape_lines(report):
    """[(label, sentence)] for the card from a plan's report (empty without the figures)."""
    if not report:
        return []
    lines = []
    fid = report.get("fidelity") or {}
    if fid.get("mean_mm") is not None:
        text = ("The simulated sheet ends %.1f mm from the file as dropped on average (9 in 10 "
                "points within %.1f mm) and reaches %s of its %.1f mm relief" % (
                    fid["mean_mm"], fid["p90_mm"], _pct(fid["relief_reached"]),
                    fid["relief_given_mm"]))
        if fid.get("right_way_strong") is not None:
            text += ("; where the file curves strongly its hills and valleys curve the right "
                     "way on %s of the area, and keep %s of their curvature" % (
                         _pct(fid["right_way_strong"]), _pct(max(fid["curvature_slope"], 0.0))))
        if fid.get("kept_from_mm") is not None:
            # An octave of scale sigma (fidelity.bands) holds most of the waves 6.5 sigma
            # long: hills and valleys 3.3 sigma across.
            text += ("; it keeps at least 80 %% of the height of hills and valleys about "
                     "%.0f mm across and wider, less of the narrower ones"
                     % (3.3 * fid["kept_from_mm"]))
        lines.append(("Against your file", text))
    sim, gate = report.get("simulation") or {}, report.get("gate") or {}
    if sim.get("mean_displacement_mm") is not None:
        limit = (gate.get("limits") or {}).get("max_mean_displacement")
        text = ("The sheet ends %.1f mm (%.1f %% of the diameter) from the shape it was planned "
                "for%s" % (sim["mean_displacement_mm"],
                           100 * sim.get("mean_displacement_fraction", 0.0),
                           _planned_as(report)))
        if limit is not None:
            text += "; the printability check allows %.1f %% of the diameter" % (100 * limit)
        lines.append(("Against the plan", text))
    return lines


def _planned_as(report):
    """What the plan changed in the file before planning: ' (...)' or ''."""
    fit = report.get("fit") or {}
    if fit.get("applied_smooth_mm") is not None:
        return " (your file smoothed %g mm)" % fit["applied_smooth_mm"]
    if fit.get("applied_scale") is not None and fit["applied_scale"] < 1.0:
        return " (your file's relief lowered to %s)" % _pct(fit["applied_scale"])
    return " (your file as given)"
