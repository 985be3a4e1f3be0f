"""The figures of the current code, written from the benchmarks' JSON, never typed.

Each benchmark group saves what it measured, with the conditions it ran under, to
``benchmarks/results/GROUP.json`` (:func:`save`); :func:`write` renders every saved
group into ``docs/figures.md`` and the headline rows into the block of ``README.md``
between ``<!-- figures:begin -->`` and ``<!-- figures:end -->``.

    python benchmarks/figures.py          # re-render from the saved results
"""

import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
BEGIN, END = "<!-- figures:begin -->", "<!-- figures:end -->"

# Whole-plan columns: header, how to read it from a model's result (None: leave blank).
# Columns whose every cell is blank are left out, so keys a method adds show when present.
# One table per question, each at most 12 columns (the model's among them).
FORM_COLUMNS = [
    ("model", lambda n, r: n),
    ("method", lambda n, r: r.get("method")),
    ("LD mm", lambda n, r: _f(r.get("longest_diameter_mm"), 0)),
    ("triangles", lambda n, r: _k(r.get("triangles"))),
    ("invalid edges", lambda n, r: _pct(r.get("invalid_edge_fraction"))),
    ("invalid area", lambda n, r: _pct(r.get("invalid_area_fraction"))),
    ("flipped", lambda n, r: r.get("flipped")),
    ("fit scale", lambda n, r: _f(r.get("fit_scale"), 2)),
    ("fit smoothed mm", lambda n, r: _f(r.get("fit_smooth_mm"), 0)),
    ("fit moved mm", lambda n, r: _f(r.get("fit_removed_mm"), 2)),
    ("reach p90", lambda n, r: _f(r.get("reach_p90"), 2)),
    ("printable", lambda n, r: _yes(r.get("printable"))),
]
SHAPE_COLUMNS = [
    ("model", lambda n, r: n),
    ("sim. displacement", lambda n, r: _disp(r)),
    ("of relief", lambda n, r: _pct(r.get("mean_displacement_of_relief"))),
    ("full-res. settle mm", lambda n, r: _f(r.get("reference_displacement_mm"), 2)),
    ("fast vs full", lambda n, r: _against(r.get("mean_displacement_mm"),
                                           r.get("reference_displacement_mm"))),
    ("at rest", lambda n, r: _rest(r)),
    ("to the input mm", lambda n, r: _fid(r, "mean_mm", 2)),
    ("p90 mm", lambda n, r: _fid(r, "p90_mm", 2)),
    ("relief reached", lambda n, r: _pct((r.get("fidelity") or {}).get("relief_reached"))),
    ("arm tips mm", lambda n, r: None if not r.get("arm_tips_mm") else
     "max %.1f" % max(r["arm_tips_mm"])),
    ("holds smoothed to", lambda n, r: None if r.get("hold_smooth_mm") is None else
     "%g mm: %s" % (r["hold_smooth_mm"], _pct(r.get("hold_displacement")))),
]
PATH_COLUMNS = [
    ("model", lambda n, r: n),
    ("traces", lambda n, r: _traces(r)),
    ("trace ends inside", lambda n, r: r.get("ends_inside")),
    ("ring bridges", lambda n, r: r.get("ring_bridges")),
    ("rim tails", lambda n, r: None if not r.get("rim_tails") else
     "%d (%.0f mm)" % (r["rim_tails"], r.get("rim_tail_mm") or 0.0)),
    ("spacing p05-p95 mm", lambda n, r: _spacing(r.get("spacing_mm"))),
    ("coverage", lambda n, r: _f(r.get("coverage"), 3)),
    ("overlap", lambda n, r: _pct(r.get("overlap"))),
    ("hops over paths", lambda n, r: _pct(r.get("hop_overprint_share"))),
    ("of it dry", lambda n, r: _pct(r.get("hop_dry_share"))),
    ("direction p95 deg", lambda n, r: _f((r.get("direction_angle_deg") or {}).get("p95"), 1)),
    ("G-code lines", lambda n, r: _k(r.get("gcode_lines"))),
]
TIME_COLUMNS = [
    ("model", lambda n, r: n),
    ("fit s", lambda n, r: _stage(r, "fit")),
    ("layout s", lambda n, r: _stage(r, "mesh", "flatten")),
    ("simulate s", lambda n, r: _stage(r, "simulate")),
    ("paths s", lambda n, r: _stage(r, "toolpath")),
    ("G-code s", lambda n, r: _stage(r, "gcode")),
    ("pictures s", lambda n, r: _stage(r, "pictures")),
    ("other s", lambda n, r: _other(r)),
    ("all stages s", lambda n, r: _all(r)),
    ("each run s", lambda n, r: _runs(r)),
    ("wall s", lambda n, r: _median(r, "wall_s")),
    ("peak RSS MB", lambda n, r: _f(r.get("peak_rss_mb"), 0)),
    ("moves/s", lambda n, r: _moves(r)),
]
TABLES = [
    ("Does it form", "the layout, the fit and the gate's verdict", FORM_COLUMNS),
    ("How close the sheet comes", "the simulated sheet against the target planned (`sim. "
     "displacement`; `full-res. settle`: the same program settled at full resolution, in the "
     "benchmark only) and against the input as given (`to the input`, `p90`, `relief "
     "reached`)", SHAPE_COLUMNS),
    ("The paths", "the lower layers' paths unless a column says otherwise", PATH_COLUMNS),
    ("Time and memory", "CPU seconds per stage on one core (BLAS threads 1) where the result "
     "has them, else wall seconds; `other`: load, validate, imports and the looks at other "
     "methods; `all stages`: CPU (wall where no CPU was kept); `each run`: a plan timed "
     "several times (the methods group's free method), every run's CPU seconds with the "
     "imports, and the stages are those of the median run; `moves/s`: the G-code's, then "
     "over the link", TIME_COLUMNS),
]
# The README's block: at most 8 columns.
README_COLUMNS = [
    ("model", lambda n, r: n),
    ("size mm", lambda n, r: _f(r.get("longest_diameter_mm"), 0)),
    ("distance to the shape", lambda n, r: _distance(r)),
    ("printable", lambda n, r: _yes(r.get("printable"))),
    ("traces", lambda n, r: _traces(r)),
    ("plan s", lambda n, r: _all(r)),
    ("print time", lambda n, r: _hours(r.get("estimated_print_s"))),
    ("peak MB", lambda n, r: _f(r.get("peak_rss_mb"), 0)),
]
HEADLINE = ("dome", "three_islands", "vancouver_island_south", "coast_mountains_bc",
            "rough_terrain")


def conditions():
    """Where and how a benchmark ran: dict of plain values."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = {}
    for mod in ("numpy", "scipy"):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:
            pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                                capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {"cpu": cpu, "cores": os.cpu_count(), "python": sys.version.split()[0],
            "versions": versions, "commit": commit or "unknown",
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "load_average": [round(x, 2) for x in os.getloadavg()],
            "single_core": True}


def save(group, data, cond=None, folder=RESULTS):
    """Keep one group's results with their conditions: ``folder/GROUP.json``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    doc = {"group": group, "conditions": cond or conditions(), "results": data}
    (folder / (group + ".json")).write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")


def load(folder=RESULTS):
    """Every saved group: dict group -> {"conditions", "results"}."""
    out = {}
    for path in sorted(Path(folder).glob("*.json")):
        doc = json.loads(path.read_text())
        if isinstance(doc, dict) and "group" in doc:   # other benchmarks keep theirs here too
            out[doc["group"]] = doc
    return out


def write(folder=RESULTS, figures=ROOT / "docs" / "figures.md", readme=ROOT / "README.md"):
    """Render ``figures`` from the saved results and the README's headline block."""
    groups = load(folder)
    Path(figures).write_text(render(groups))
    readme = Path(readme)
    if readme.exists():
        readme.write_text(replace_block(readme.read_text(), headline(groups)))


def render(groups):
    """docs/figures.md text for ``groups`` (see :func:`load`)."""
    out = ["# Figures", "",
           "Written by `benchmarks/` from their results (`benchmarks/results/*.json`); "
           "re-run a benchmark to renew its section. Times are on one core (BLAS threads 1) "
           "unless a section says otherwise; \"at rest\" counts L-BFGS iterations of the "
           "forward simulation (coarse sheet + full mesh).", ""]
    models = {}
    for name in ("plan", "terrain", "fine_map"):
        for model, r in _models(groups.get(name, {}).get("results", {})).items():
            models[model] = r
    if models:
        out += ["## Whole plan (`benchmarks/pipeline.py`)", ""]
        out += _tables(models, _conditions(groups, ("plan", "terrain", "fine_map")), "###")
    both = _models(groups.get("methods", {}).get("results", {}))
    if both:
        out += ["## Both layout methods, one simulation (`benchmarks/pipeline.py --only methods`)",
                "", "Whole plans, each checked by the thin-shell simulation (printed thickness; "
                "its answer changes by under 10 % when the mesh is halved). `free`: the relief "
                "fitted to the material (`hostd plan --fit`, also where a sidecar asks for a "
                "height), started flat with the curvature programmed through the layers; "
                "`traces` a + b where the lower and upper layer groups print paths of their own "
                "(turned apart by the twist), `+ c across` where two layers (the second and second "
                "last) print paths across the others' (the curvature across them); `trace "
                "ends inside`: the lower layers' trace ends more than a path width from the "
                "outline, where the stripes fork and no hop within its budget joins them (the "
                "traces are at least half as many); `ring bridges`: the lower layers' closed "
                "paths bridged into a path beside them; `rim tails`: the lower layers' ends at "
                "the edge joined to the path beside them, that path's tail along the edge left "
                "out (`toolpath.rim_tail_widths` widths at most; their length left bare); "
                "`hops over paths`: the length of the lower "
                "layers' hops that runs over other paths, or back over the two it joins "
                "(`toolpath.hop_over_widths` a hop at most), as a share of their path length; "
                "`of it dry`: the share the nozzle moves over without extruding (stretches of "
                "two widths or more); the rest is plastic printed twice that `overlap`, taken "
                "over the paths alone, does not see. "
                "`isoline`: the paper's layout as given, its sheet resampled onto the plan's grid "
                "(`mesh.grid_mm`; `flatten.simulation: shell`), started from a bump. Rows `at 175 mm`: the real "
                "tile again at the size the time targets name, with the default method; the row `rough_terrain "
                "175 mm across`: the generated terrain (a 175 mm square) again as a square 175 mm "
                "across its diagonal, a real tile's size, its detail the same per mm; rows `lowered "
                "only`: the real tile fitted by lowering its relief alone (`fit: relief`). `fit "
                "smoothed`: the smoothing the fit applied instead of lowering the relief, `fit "
                "moved`: the mean height change the fit made to the input (either lever), "
                "`reach p90`: the planned target's curvature over the most the layers can curl "
                "(above 0.4 narrow features do not form). Load to "
                "simulation counts the fit (it solves the plan's layout). `of relief`: the mean "
                "displacement over the relief planned (a quarter or more and the hills and "
                "valleys hardly show).", ""]
        out += _tables(both, _conditions(groups, ("methods",)), "###")
    layout = _models(groups.get("layout", {}).get("results", {}))
    if layout:
        out += ["## Layout methods side by side (`benchmarks/pipeline.py --only layout`)", "",
                "The paper's isoline method against the free print direction, layout stage "
                "only (profile `generic-0.5mm`; free method on a 1 mm grid, 200 iterations). "
                "Invalid edges: the share of printing edges (isoline) or of triangle edges along "
                "the print direction (free) whose shrink leaves the printable range; invalid "
                "area: the share of the sheet in such triangles (isoline) or whose map leaves "
                "the admissible set by more than 1 % (free).", "",
                "| model | method | triangles | invalid edges | stretch | invalid area "
                "(stretch / overshrink) | flipped | flatten s | peak RSS MB |",
                "|---|---|---|---|---|---|---|---|---|"]
        for name, r in layout.items():
            area = (None if r.get("invalid_area_fraction") is None else "%s (%s / %s)" % (
                _pct(r["invalid_area_fraction"]), _pct(r.get("stretch_area_fraction")) or "-",
                _pct(r.get("overshrink_area_fraction")) or "-"))
            cells = [name.split(" ")[0], r["method"], _k(r.get("triangles")),
                     _pct(r.get("invalid_edge_fraction")), _pct(r.get("stretch_edge_fraction")),
                     area, r.get("flipped"), _f(r.get("flatten_s"), 1),
                     _f(r.get("peak_rss_mb"), 0)]
            out.append("| " + " | ".join("" if c is None else str(c) for c in cells) + " |")
        out += [""] + _conditions(groups, ("layout",))
    flat = groups.get("flatten", {}).get("results", {})
    if flat:
        out += ["## Flattening scaling (`benchmarks/pipeline.py --only flatten`)", "",
                "| triangles | flatten s | peak RSS MB |", "|---|---|---|"]
        for r in flat.values():
            if isinstance(r, dict) and "triangles" in r:
                out.append("| %s | %s | %s |" % (_k(r["triangles"]), r.get("flatten_s"),
                                                 _f(r.get("peak_rss_mb"), 0)))
        out += [""] + _conditions(groups, ("flatten",))
    return "\n".join(out).rstrip() + "\n"


def headline(groups):
    """The README's rows: the free method's plans of the headline models in the methods
    group (the current code's default), with a link to the rest."""
    models = {}
    for model, r in _models(groups.get("methods", {}).get("results", {})).items():
        # The relief-only fit is a comparison for docs/figures.md, not a plan as shipped.
        if (model.split(" ")[0] in HEADLINE and r.get("method") == "free"
                and "lowered only" not in model):
            models[model] = r
    if not models:
        return "No benchmark has been run yet: `python benchmarks/pipeline.py`."
    cond = groups["methods"]["conditions"]
    runs = max(len(((r.get("repeats") or {}).get("plan_cpu_s") or {}).get("runs", [0]))
               for r in models.values())
    return "\n".join(_table(models, README_COLUMNS) + [
        "", "%s, one core (BLAS threads 1), commit %s (%s), the free layout method (the "
        "relief fitted to the material). `plan s`: every stage's CPU seconds with the "
        "imports%s; `distance to the shape`: the simulated sheet from the input as given.%s "
        "Both methods and every figure, with its conditions: [docs/figures.md]"
        "(docs/figures.md)." % (
            cond.get("cpu", "?"), cond.get("commit", "?"), cond.get("date", "?"),
            ", the median of %d runs" % runs if runs > 1 else "", _load_probe(models))])


def _load_probe(models):
    """What the imports say of the machine's load: they do the same work in every run,
    so where a neighbour shared the machine they read higher, as every figure did."""
    imports = [r["imports"]["cpu_s"] for r in models.values()
               if isinstance(r.get("imports"), dict) and "cpu_s" in r["imports"]]
    if not imports:
        return ""
    return (" The imports, the same work in every plan, took %.2f-%.2f s of CPU: where a "
            "neighbour loads the machine they read higher, and so does every figure."
            % (min(imports), max(imports)))


def replace_block(text, body):
    """``text`` with the figures block's body replaced (appended if it has none)."""
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        _, tail = rest.split(END, 1)
        return head + BEGIN + "\n" + body + "\n" + END + tail
    return text.rstrip("\n") + "\n\n" + BEGIN + "\n" + body + "\n" + END + "\n"


def _models(results):
    """Flatten a group's results to {model label: result}, skipping errors; a model
    planned by several methods gives one row per method."""
    out = {}
    if "triangles" in results:               # a group of one model (fine_map)
        results = {"fine map (16 MP)": results}
    for model, r in results.items():
        if not isinstance(r, dict) or "error" in r or "skipped" in r:
            continue
        if "methods" in r:
            for method, rm in r["methods"].items():
                if isinstance(rm, dict) and "error" not in rm:
                    out["%s (%s)" % (model, method)] = dict(rm, method=method)
        else:
            out[model] = r
    return out


def _tables(models, conditions, level):
    """One table per question of :data:`TABLES` for ``models``, each headed by the
    question, what it shows, and the ``conditions`` lines of its runs."""
    out = []
    for title, shows, columns in TABLES:
        rows = _table(models, columns)
        if rows:
            out += ["%s %s" % (level, title), "", shows[0].upper() + shows[1:] + ".", "",
                    *rows, "", *conditions]
    return out


def _table(models, columns):
    """Markdown rows of ``models`` under ``columns`` ((header, reader) pairs), the
    columns blank on every model left out; [] where only the model's is left."""
    cells = {name: [f(name, r) for _, f in columns] for name, r in models.items()}
    used = [i for i in range(len(columns)) if any(c[i] not in (None, "") for c in cells.values())]
    if len(used) <= 1:
        return []
    lines = ["| " + " | ".join(columns[i][0] for i in used) + " |",
             "|" + "---|" * len(used)]
    for row in cells.values():
        lines.append("| " + " | ".join("" if row[i] is None else str(row[i]) for i in used) + " |")
    return lines


def _conditions(groups, names):
    out = []
    for name in names:
        c = groups.get(name, {}).get("conditions")
        if c:
            v = ", ".join("%s %s" % kv for kv in sorted(c.get("versions", {}).items()))
            out.append("*%s*: %s, %s cores, Python %s, %s; commit %s, %s, load average %s." % (
                name, c.get("cpu"), c.get("cores"), c.get("python"), v, c.get("commit"),
                c.get("date"), " / ".join(str(x) for x in c.get("load_average", []))))
    return out + [""] if out else []


def _f(v, digits):
    return None if v is None else ("%.*f" % (digits, v))


def _k(v):
    return None if v is None else ("%.0fk" % (v / 1000) if v >= 10000 else str(v))


def _pct(v):
    return None if v is None else "%.1f %%" % (100 * v)


def _traces(r):
    """Traces per layer of each set of paths the plan prints."""
    if not r.get("upper_traces") and not r.get("across_traces"):
        return r.get("traces")
    parts = ["%d" % r["traces"]] + (["%d" % r["upper_traces"]] if r.get("upper_traces") else [])
    return " + ".join(parts + (["%d across" % r["across_traces"]] if r.get("across_traces") else []))


def _disp(r):
    mm, pct = r.get("mean_displacement_mm"), r.get("mean_displacement_pct_of_diameter")
    return None if mm is None else "%.2f mm (%.2f %%)" % (mm, pct)


def _rest(r):
    if "simulation_converged" not in r:
        return None
    coarse = r.get("coarse_iterations", 0)
    full = r.get("full_iterations")
    if full is None:        # results from before the report counted them apart
        full = r.get("simulation_iterations", 0) - coarse
    return "%s (%s + %s)" % ("yes" if r["simulation_converged"] else "no", coarse, full)


def _yes(v):
    return None if v is None else ("yes" if v else "no")


def _fid(r, key, digits):
    return _f((r.get("fidelity") or {}).get(key), digits)


def _against(fast, full):
    """The fast settle's mean displacement against the full-resolution one's."""
    if fast is None or full is None:
        return None
    return "%+.2f mm (%+.0f %%)" % (fast - full, 100 * (fast - full) / max(full, 1e-9))


def _distance(r):
    """Distance to the shape: to the input as given where the report has it, else the
    simulated sheet's mean displacement from the target planned."""
    mean = (r.get("fidelity") or {}).get("mean_mm")
    if mean is not None:
        return "%.2f mm" % mean
    return None if r.get("mean_displacement_mm") is None else "%.2f mm" % r["mean_displacement_mm"]


def _stage(r, *names):
    """CPU seconds of the stages ``names`` (wall, from ``timing_s``, where no CPU kept)."""
    stages = r.get("stages")
    if stages:
        got = [stages[n]["cpu_s"] for n in names if n in stages]
        return _f(sum(got), 1) if got else None
    got = [(r.get("timing_s") or {}).get(n) for n in names]
    got = [g for g in got if g is not None]
    return _f(sum(got), 1) if got else None


def _other(r):
    stages = r.get("stages")
    if not stages:
        return None
    main = {"fit", "mesh", "flatten", "simulate", "toolpath", "gcode", "pictures"}
    rest = sum(v["cpu_s"] for k, v in stages.items() if k not in main)
    return _f(rest + (r.get("imports") or {}).get("cpu_s", 0.0), 1)


def _all(r):
    """Every stage's CPU seconds and the imports (else the wall seconds kept)."""
    if r.get("cpu_s") is not None:
        return _f(r["cpu_s"] + (r.get("imports") or {}).get("cpu_s", 0.0), 1)
    return _median(r, "all_stages_s")


def _runs(r):
    """Every timed run's CPU seconds with the imports, where a plan was timed more than
    once."""
    rep = (r.get("repeats") or {}).get("plan_cpu_s")
    return None if not rep else ", ".join("%.1f" % x for x in rep["runs"])


def _moves(r):
    if r.get("moves_per_s") is None:
        return None
    link = r.get("link_moves_per_s")
    return "%.0f" % r["moves_per_s"] + ("" if link is None else " / %.0f" % link)


def _hours(seconds):
    if seconds is None:
        return None
    minutes = int(round(seconds / 60.0))
    return "%d h %02d min" % divmod(minutes, 60)


def _spacing(s):
    return None if not s else "%.3f-%.3f" % (s["p05"], s["p95"])


def _median(r, key):
    rep = (r.get("repeats") or {}).get(key)
    if rep:
        return "%.1f (%s)" % (rep["median"], ", ".join("%.1f" % x for x in rep["runs"]))
    return _f(r.get(key), 1)


if __name__ == "__main__":
    write()
