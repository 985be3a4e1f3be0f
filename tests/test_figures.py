"""docs/figures.md and the README's figures block are written from benchmark results."""

import importlib.util
from pathlib import Path

# Loaded from its file: with benchmarks/ on sys.path its pipeline.py would stand in for
# the pipeline package in every test module collected after this one.
_spec = importlib.util.spec_from_file_location(
    "figures", Path(__file__).resolve().parents[1] / "benchmarks" / "figures.py")
figures = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(figures)

COND = {"cpu": "Test CPU", "cores": 2, "python": "3.11.7", "versions": {"numpy": "2.0"},
        "commit": "abc1234", "date": "2026-01-01 00:00 UTC", "load_average": [0.5, 0.4, 0.3]}
DOME = {"longest_diameter_mm": 175.0, "triangles": 88000, "invalid_edge_fraction": 0.0,
        "mean_displacement_mm": 0.07, "mean_displacement_pct_of_diameter": 0.04,
        "simulation_converged": True, "simulation_iterations": 225, "coarse_iterations": 176,
        "traces": 1, "spacing_mm": {"p05": 0.479, "p50": 0.48, "p95": 0.482}, "coverage": 0.993,
        "load_to_simulation_s": 8.4, "all_stages_s": 10.1, "wall_s": 12.8, "peak_rss_mb": 411,
        "gcode_lines": 261000, "moves_per_s": 39.0,
        "repeats": {"all_stages_s": {"runs": [10.1, 10.8, 10.0], "median": 10.1}}}


def test_the_table_is_written_from_the_results_and_new_keys_show_when_present(tmp_path):
    res = tmp_path / "results"
    figures.save("plan", {"dome": DOME, "broken": {"error": "boom"}}, COND, folder=res)
    text = figures.render(figures.load(res))
    assert "| dome |" in text and "0.04 %" in text and "10.1 (10.1, 10.8, 10.0)" in text
    assert "broken" not in text and "invalid area" not in text
    assert "Test CPU" in text and "abc1234" in text
    free = dict(DOME, invalid_area_fraction=0.012, link_moves_per_s=199.0)
    figures.save("plan", {"dome": {"methods": {"isoline": DOME, "free": free}}}, COND, folder=res)
    text = figures.render(figures.load(res))
    assert "| dome (isoline) | isoline |" in text and "| dome (free) | free |" in text
    assert "invalid area" in text and "1.2 %" in text and "199" in text


def test_only_the_readme_block_is_replaced(tmp_path):
    res = tmp_path / "results"
    figures.save("plan", {"dome": DOME, "starfish": DOME}, COND, folder=res)
    readme = tmp_path / "README.md"
    readme.write_text("# hostd\n\nintro\n\n%s\nold numbers\n%s\n\n## After\ntext\n"
                      % (figures.BEGIN, figures.END))
    figures.write(res, tmp_path / "figures.md", readme)
    text = readme.read_text()
    assert text.startswith("# hostd\n\nintro\n\n") and text.endswith("\n## After\ntext\n")
    # The README shows the default (free) method's plans only: the isoline whole-plan
    # group stays in docs/figures.md.
    assert "old numbers" not in text and "paper's sim." not in text
    figures.save("methods", {"dome": {"methods": {"free": dict(DOME, fit_scale=1.0),
                                                  "isoline": DOME}},
                             "starfish": {"methods": {"free": dict(DOME, fit_scale=1.0)}}},
                 COND, folder=res)
    figures.write(res, tmp_path / "figures.md", readme)
    text = readme.read_text()
    assert "| dome (free) |" in text and "(isoline)" not in text and "starfish" not in text
    assert "docs/figures.md" in text
    assert "| starfish |" in (tmp_path / "figures.md").read_text()


def _widest(text):
    return max(line.count("|") - 1 for line in text.splitlines() if line.startswith("|"))


FREE = dict(DOME, method="free", fit_scale=1.0, fit_smooth_mm=6.0, fit_removed_mm=0.4,
            reach_p90=0.3, invalid_area_fraction=0.01, flipped=0, printable=True,
            upper_traces=1, across_traces=1, ends_inside=0, ring_bridges=3, rim_tails=2,
            rim_tail_mm=9.0, overlap=0.01, hop_overprint_share=0.02, hop_dry_share=0.01,
            direction_angle_deg={"p95": 4.0}, link_moves_per_s=250.0,
            estimated_print_s=5580.0, mean_displacement_of_relief=0.03,
            reference_displacement_mm=0.08, hold_smooth_mm=8.0, hold_displacement=0.004,
            arm_tips_mm=[1.0, 2.0], imports={"wall_s": 1.0, "cpu_s": 0.8},
            stages={"load": {"wall_s": 0.1, "cpu_s": 0.1}, "fit": {"wall_s": 2.0, "cpu_s": 1.5},
                    "mesh": {"wall_s": 0.3, "cpu_s": 0.2}, "flatten": {"wall_s": 2.0, "cpu_s": 1.8},
                    "simulate": {"wall_s": 4.0, "cpu_s": 3.0},
                    "toolpath": {"wall_s": 3.0, "cpu_s": 2.5}, "gcode": {"wall_s": 1, "cpu_s": 0.6},
                    "pictures": {"wall_s": 1.2, "cpu_s": 0.9}},
            cpu_s=10.6, fidelity={"mean_mm": 0.61, "p90_mm": 1.4, "relief_reached": 0.93})


def test_every_table_answers_one_question_in_at_most_twelve_columns(tmp_path):
    res = tmp_path / "results"
    figures.save("methods", {"dome": {"methods": {"free": FREE, "isoline": DOME}}}, COND,
                 folder=res)
    text = figures.render(figures.load(res))
    assert _widest(text) <= 12
    for title, _, _ in figures.TABLES:
        assert "### " + title in text
    # CPU per stage, the pictures apart; the imports count in all stages and in `other`.
    assert "| dome (free) | 1.5 | 2.0 | 3.0 | 2.5 | 0.6 | 0.9 | 0.9 | 11.4 |" in text
    # The fast settle beside the full-resolution one, and the distance to the input.
    assert "0.08" in text and "-0.01 mm (-12 %)" in text
    assert "| 0.61 | 1.40 | 93.0 % |" in text
    # A result without those keys leaves their cells blank, not the table.
    row = next(line for line in text.splitlines() if line.startswith("| dome (isoline) |")
               and "0.07 mm" in line)
    assert "| 0.08 |" not in row


def test_the_readme_block_has_at_most_eight_columns_with_the_plan_time_and_memory(tmp_path):
    res = tmp_path / "results"
    figures.save("methods", {"dome": {"methods": {"free": FREE}}}, COND, folder=res)
    block = figures.headline(figures.load(res))
    assert _widest(block) <= 8
    head = block.splitlines()[0]
    for column in ("model", "distance to the shape", "printable", "traces", "plan s",
                   "print time", "peak MB"):
        assert column in head
    assert "| dome (free) | 175 | 0.61 mm | yes | 1 + 1 + 1 across | 11.4 | 1 h 33 min | 411 |" \
        in block


def test_at_rest_counts_the_coarse_sheet_and_the_plans_mesh_apart(tmp_path):
    """The free method's settle reports its coarse trials apart from the plan's mesh's
    iterations, the paper's forward simulation both stages in one count: each row says
    coarse + plan's mesh, neither negative."""
    res = tmp_path / "results"
    staged = dict(DOME, simulation_iterations=70, coarse_iterations=571, full_iterations=70)
    figures.save("plan", {"dome": {"methods": {"isoline": DOME, "free": staged}}}, COND,
                 folder=res)
    text = figures.render(figures.load(res))
    assert "yes (571 + 70)" in text and "yes (176 + 49)" in text and "+ -" not in text


def test_a_plan_timed_several_times_shows_its_median_and_every_run(tmp_path):
    """The methods group times each free-method plan more than once on a shared machine:
    the README names the median and how many runs, docs/figures.md every run."""
    res = tmp_path / "results"
    timed = dict(DOME, fit_scale=1.0, cpu_s=9.4, imports={"cpu_s": 0.6},
                 stages={"simulate": {"wall_s": 2.0, "cpu_s": 2.0}},
                 repeats={"plan_cpu_s": {"runs": [10.0, 12.5, 9.6], "median": 10.0}})
    figures.save("methods", {"dome": {"methods": {"free": timed}}}, COND, folder=res)
    readme = tmp_path / "README.md"
    readme.write_text("# hostd\n")
    figures.write(res, tmp_path / "figures.md", readme)
    assert "| 10.0 |" in readme.read_text() and "the median of 3 runs" in readme.read_text()
    assert "The imports, the same work in every plan, took 0.60-0.60 s of CPU" in (
        readme.read_text())
    assert "| 10.0 | 10.0, 12.5, 9.6 |" in (tmp_path / "figures.md").read_text()
