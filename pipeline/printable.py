"""Will the sheet form the shape? The profile's limits (``printable``) on the plan's figures.

A plan can be laid out, simulated and given tool paths and still not form what was
dropped: much of the sheet needing a shrink the material cannot make, a simulated sheet
far from the target, paths that leave gaps. Within the profile's limits a plan prints by
itself; outside them it is planned, but a person decides (the daemon holds the job at
``ready`` until someone approves it).
"""

# A shrink outside [s_min, s_max] by more than this counts as one the material cannot
# make: 1e-3 is far below what layer thickness can resolve (the shrink curve spans ~0.34
# over ~0.1 mm of thickness) and well above solver round-off.
SIGMA_TOL = 1e-3

# Codes of the problems that hold a plan for a person's decision.
CODES = ("printable.invalid_area", "printable.displacement", "printable.coverage")


def figures(report):
    """The figures the limits apply to, as fractions: ``invalid_area``,
    ``mean_displacement`` (of the longest diameter) and ``coverage``."""
    return {"invalid_area": float(report["flatten"].get("invalid_area_fraction", 0.0)),
            "mean_displacement": float(report["simulation"]["mean_displacement_fraction"]),
            "coverage": float(report["toolpath"].get("coverage", 1.0))}


def gate(report, limits, name="NAME"):
    """The report's ``gate`` section and the problems of a plan outside ``limits``
    (a :class:`pipeline.profiles.schema.PrintableLimits`)."""
    got = figures(report)
    diameter = report["heightfield"]["longest_diameter_mm"]
    problems = []
    if got["invalid_area"] > limits.max_invalid_area:
        problems.append({
            "code": "printable.invalid_area",
            "message": "%.0f %% of the sheet needs a shrink the material cannot make (the "
                       "profile allows %.0f %%): the sheet will not reach the shape there"
                       % (100 * got["invalid_area"], 100 * limits.max_invalid_area),
            "fix": "lower the relief (height_mm in the sidecar) or smooth it (smooth_mm); "
                   "saddles and valleys form with flatten.method: free; %s.stress.png shows "
                   "where" % name})
    if got["mean_displacement"] > limits.max_mean_displacement:
        problems.append({
            "code": "printable.displacement",
            "message": "the simulated sheet ends %.1f mm from the shape on average, %.1f %% "
                       "of its %.0f mm diameter (the profile allows %.1f %%)"
                       % (got["mean_displacement"] * diameter, 100 * got["mean_displacement"],
                          diameter, 100 * limits.max_mean_displacement),
            "fix": "%s.preview.png shows where the sheet departs; a lower or smoother relief "
                   "departs less" % name})
    if got["coverage"] < limits.min_coverage:
        problems.append({
            "code": "printable.coverage",
            "message": "the tool paths cover %.0f %% of the sheet (the profile asks for %.0f "
                       "%%): the printed sheet will have gaps" % (
                           100 * got["coverage"], 100 * limits.min_coverage),
            "fix": "%s.toolpath.png shows where; gaps open where paths must spread apart, "
                   "which a smoother relief avoids" % name})
    section = {"limits": {"max_invalid_area": limits.max_invalid_area,
                          "max_mean_displacement": limits.max_mean_displacement,
                          "min_coverage": limits.min_coverage},
               "figures": got, "outside": [p["code"] for p in problems]}
    return section, problems
