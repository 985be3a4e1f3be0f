"""Calibration (paper section 6, Fig. 2): print rectangles, fit measurements, update the profile."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from gcode_parser import parse
from hostd.cli import main
from pipeline.profiles.calibration import (COLUMNS, fit_measurements, layout_plates, read_measurements,
                                  thickness_values)
from pipeline.errors import PlanError
from pipeline.profiles.profile import load_profile

REPO = Path(__file__).resolve().parents[1]
GENERIC = REPO / "profiles" / "generic-0.5mm.yaml"


def true_shrink(t):
    """A known monotonic curve (34 % at 0.1 mm to ~1 % at 0.45 mm), degree 3."""
    x = (t - 0.1) / 0.35
    return 0.34 - 0.62 * x + 0.38 * x ** 2 - 0.09 * x ** 3


@pytest.fixture()
def profile_copy(tmp_path):
    path = tmp_path / "myprinter.yaml"
    shutil.copy(GENERIC, path)
    return path


@pytest.fixture(scope="module")
def printed(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal")
    assert main(["calibrate", "print", "--profile", "generic-0.5mm", "-o", str(out)]) == 0
    return out


def _fill(csv_path, shrink_of, noise=0.0, seed=0, edit=None):
    """Write measured lengths into a template: printed * (1 - shrink(thickness) + noise)."""
    rng = np.random.default_rng(seed)
    lines = csv_path.read_text().splitlines()
    out = []
    header = None
    for no, ln in enumerate(lines, 1):
        if ln.startswith("#") or not ln.strip():
            out.append(ln)
            continue
        if header is None:
            header = ln.split(",")
            out.append(ln)
            continue
        cells = ln.split(",")
        t, printed = float(cells[1]), float(cells[3])
        cells[4] = "%.2f" % (printed * (1 - shrink_of(t) + noise * rng.standard_normal()))
        if edit:
            cells = edit(no, cells)
        out.append(",".join(cells))
    csv_path.write_text("\n".join(out) + "\n")
    return csv_path


def test_print_writes_rectangles_of_the_right_size(printed):
    p = load_profile("generic-0.5mm")
    files = sorted(printed.glob("calibration*.gcode"))
    assert files, "no G-code written"
    w = p.path_width_mm
    n_paths = round(20 / w)
    seen = {}
    for f in files:
        g = parse(f.read_text())
        labels = [c for c in g.comments if c.startswith("SPECIMEN:")]
        for layer in range(1, p.layers + 1):
            runs = g.runs(layer)
            # one continuous run per rectangle per layer (boustrophedon)
            assert len(runs) == len(labels) // p.layers
            for run in runs:
                xy = np.array([m.end[:2] for m in run] + [run[0].start[:2]])
                size = np.ptp(xy, axis=0) + w  # outer size: centrelines plus a bead
                long_side, short_side = max(size), min(size)
                assert long_side == pytest.approx(55.0, abs=1e-3)
                assert short_side == pytest.approx(n_paths * w, abs=1e-3)
                assert abs(short_side - 20.0) <= w / 2
                # constant thickness within a rectangle, Z = layer * thickness
                z = np.array([m.end[2] for m in run])
                assert np.ptp(z) == 0
                seen.setdefault((f.name, *np.round(xy.min(0), 3)), []).append((layer, z[0]))
                assert np.all(xy >= 0) and np.all(xy <= np.array(p.bed_mm))
    # N values x R repeats rectangles in total
    assert len(seen) == 11 * 3
    thick = []
    for zs in seen.values():
        theta = zs[0][1]
        assert [z for _, z in zs] == pytest.approx([k * theta for k, _ in zs], abs=1e-9)
        thick.append(round(theta, 3))
    expected = thickness_values(p.thickness_mm.min, p.thickness_mm.max, 11)
    assert sorted(set(thick)) == pytest.approx(sorted(expected))
    assert all(thick.count(t) == 3 for t in set(thick))


def test_print_writes_layout_svg_and_csv_template(printed):
    svg = (printed / "calibration_layout.svg").read_text()
    assert svg.startswith("<svg") and svg.rstrip().endswith("</svg>")
    for i in range(1, 34):
        assert "SPECIMEN:%d " % i in svg
    text = (printed / "measurements.csv").read_text()
    assert "80-90 C" in text and "along the printed paths".lower() in text.lower()
    rows = [ln for ln in text.splitlines() if ln and not ln.startswith("#")]
    assert rows[0] == ",".join(COLUMNS)
    cells = [r.split(",") for r in rows[1:]]
    assert len(cells) == 33
    assert all(c[3] == "55" and c[4] == "" for c in cells)
    assert sorted(int(c[0]) for c in cells) == list(range(1, 34))


def test_print_refuses_to_clobber_measurements(tmp_path, capsys):
    out = tmp_path / "cal"
    args = ["calibrate", "print", "--profile", "generic-0.5mm", "-o", str(out), "--values", "5",
            "--repeats", "1"]
    assert main(args) == 0
    _fill(out / "measurements.csv", true_shrink)
    before = (out / "measurements.csv").read_text()
    assert main(args) == 1
    assert "calibration.would_overwrite" in capsys.readouterr().err
    assert (out / "measurements.csv").read_text() == before
    assert main(args + ["--force"]) == 0


def test_layout_fits_the_bed_or_says_why():
    th = thickness_values(0.1, 0.45, 11)
    # the paper's 33 rectangles fit one load of a large bed ...
    plates = layout_plates(th, 3, (300, 300))
    assert len(plates) == 1 and len(plates[0]) == 33
    # ... and take two on a 220 mm bed unless told to use one
    assert len(layout_plates(th, 3, (220, 220))) == 2
    with pytest.raises(PlanError) as exc:
        layout_plates(th, 3, (220, 220), plates=1)
    assert exc.value.code == "calibration.bed_too_small" and "33" in str(exc.value)
    with pytest.raises(PlanError) as exc:
        layout_plates(th, 3, (50, 50))
    assert exc.value.code == "calibration.bed_too_small"
    for plate in plates:
        boxes = [(s.x_mm, s.y_mm, s.x_mm + s.size_xy_mm[0], s.y_mm + s.size_xy_mm[1])
                 for s in plate]
        for i, a in enumerate(boxes):
            assert a[0] >= 0 and a[1] >= 0 and a[2] <= 300 and a[3] <= 300
            for b in boxes[i + 1:]:  # no two rectangles overlap
                assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1]


def test_round_trip_recovers_known_curve(tmp_path, profile_copy, capsys):
    out = tmp_path / "cal"
    assert main(["calibrate", "print", "--profile", str(profile_copy), "-o", str(out)]) == 0
    _fill(out / "measurements.csv", true_shrink, noise=0.002, seed=1)
    new = tmp_path / "myprinter-calibrated.yaml"
    original = profile_copy.read_bytes()
    assert main(["calibrate", "fit", str(out / "measurements.csv"), "--profile",
                 str(profile_copy), "-o", str(new)]) == 0
    text = capsys.readouterr().out
    assert "RMS" in text and "usable shrink range" in text
    assert profile_copy.read_bytes() == original
    cal = load_profile(new)
    assert cal.name == "myprinter-calibrated" and cal.warnings == ()
    grid = np.linspace(0.1, 0.45, 50)
    fitted = cal.shrink_curve.sigma(grid)
    assert np.max(np.abs(fitted - true_shrink(grid))) < 0.006
    # points are the per-thickness means of the repeats
    assert len(cal.shrink_curve.thickness_mm) == 11
    lo, hi = cal.shrink_curve.sigma_range
    assert cal.shrink_limits.s_max == pytest.approx(hi, abs=1e-4)
    assert cal.shrink_limits.s_min == pytest.approx(max(lo, 0), abs=1e-4)
    assert hi == pytest.approx(true_shrink(0.1), abs=0.006)
    # other settings are carried over
    assert cal.bed_mm == load_profile(profile_copy).bed_mm
    assert cal.gcode == load_profile(profile_copy).gcode


def test_fit_residuals_and_rms():
    t = np.repeat(thickness_values(0.1, 0.45, 11), 3)
    rng = np.random.default_rng(3)
    noise = 0.003 * rng.standard_normal(len(t))
    lines = ["specimen,thickness_mm,repeat,printed_length_mm,measured_length_mm"]
    for i, (ti, ni) in enumerate(zip(t, noise)):
        lines.append("%d,%g,%d,55,%.4f" % (i + 1, ti, i % 3 + 1, 55 * (1 - true_shrink(ti) - ni)))
    rows = read_measurements("\n".join(lines))
    fit = fit_measurements(rows, degree=4, theta_range_mm=(0.1, 0.45))
    assert fit.rms == pytest.approx(np.std(noise), rel=0.35)
    assert np.allclose(fit.residuals, [r.shrink for r in rows] - fit.curve.sigma(t))
    assert fit.shrink_range[1] == pytest.approx(0.34, abs=0.006)


def test_original_profile_never_overwritten(tmp_path, profile_copy, capsys):
    out = tmp_path / "cal"
    main(["calibrate", "print", "--profile", str(profile_copy), "-o", str(out), "--values", "6",
          "--repeats", "1"])
    csv_path = _fill(out / "measurements.csv", true_shrink)
    original = profile_copy.read_bytes()
    for force in ([], ["--force"]):
        assert main(["calibrate", "fit", str(csv_path), "--profile", str(profile_copy),
                     "-o", str(profile_copy)] + force) == 1
        assert "calibration.would_overwrite_profile" in capsys.readouterr().err
        assert profile_copy.read_bytes() == original
    # a different existing file only with --force
    other = tmp_path / "other.yaml"
    other.write_text("keep me")
    assert main(["calibrate", "fit", str(csv_path), "--profile", str(profile_copy),
                 "-o", str(other)]) == 1
    assert "calibration.would_overwrite" in capsys.readouterr().err
    assert other.read_text() == "keep me"
    assert main(["calibrate", "fit", str(csv_path), "--profile", str(profile_copy),
                 "-o", str(other), "--force"]) == 0
    assert load_profile(other).shrink_curve.degree == 4


def _csv(rows):
    return "\n".join(["# comment", ",".join(COLUMNS)] + rows) + "\n"


GOOD = ["%d,%g,1,55,%.2f" % (i + 1, t, 55 * (1 - true_shrink(t)))
        for i, t in enumerate(thickness_values(0.1, 0.45, 6))]


@pytest.mark.parametrize("rows, code, line, words", [
    (GOOD[:2] + ["3,0.24,1,55,55.9"] + GOOD[3:], "calibration.growth", 5, "grew"),
    (GOOD[:3] + ["4,0.31,1,55,"] + GOOD[4:], "calibration.missing_value", 6, "empty"),
    (GOOD[:1] + ["2,0.17,1,55,4O.2"] + GOOD[2:], "calibration.not_a_number", 4, "not a number"),
    (GOOD[:1] + ["2,abc,1,55,40"] + GOOD[2:], "calibration.not_a_number", 4, "thickness_mm"),
    (GOOD[:1] + ["2,0.17,1,0,40"] + GOOD[2:], "calibration.not_positive", 4, "positive"),
    # 0.17 mm measured to shrink as little as 0.31 mm: shrink rises from 0.17 to 0.24 mm
    (GOOD[:1] + ["2,0.17,1,55,%.2f" % (55 * (1 - true_shrink(0.31)))] + GOOD[2:],
     "calibration.not_monotonic", None, "rises"),
    (GOOD[:4], "calibration.too_few", None, "too few"),
    (GOOD + ["7,0.1,2,55,%.2f" % (55 * (1 - 0.25))], "calibration.repeats_disagree", 9,
     "disagree"),
])
def test_bad_measurements_rejected_with_clear_message(tmp_path, profile_copy, capsys, rows,
                                                      code, line, words):
    csv_path = tmp_path / "m.csv"
    csv_path.write_text(_csv(rows))
    new = tmp_path / "new.yaml"
    assert main(["calibrate", "fit", str(csv_path), "--profile", str(profile_copy),
                 "-o", str(new)]) == 1
    err = capsys.readouterr().err
    assert code in err and words in err
    if line:
        assert "line %d" % line in err
    assert not new.exists() and not list(tmp_path.glob("*.part"))


def test_good_measurements_fit(tmp_path, profile_copy):
    csv_path = tmp_path / "m.csv"
    csv_path.write_text(_csv(GOOD))
    assert main(["calibrate", "fit", str(csv_path), "--profile", str(profile_copy),
                 "-o", str(tmp_path / "new.yaml")]) == 0


def test_missing_column_and_empty_file():
    with pytest.raises(Exception) as exc:
        read_measurements("specimen,thickness_mm,repeat,printed_length_mm\n1,0.1,1,55\n")
    assert exc.value.code == "calibration.columns"
    with pytest.raises(Exception) as exc:
        read_measurements("# nothing\n")
    assert exc.value.code == "calibration.empty"
