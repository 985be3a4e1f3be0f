"""Calibration of the layers across: strips whose second and second-last layers print
along them with a thickness difference, every other layer across them; their measured
curl fitted to the constant of the layers across, which the plan then uses."""

import csv

import numpy as np
import pytest
import yaml

from gcode_parser import parse
from hostd.cli import main
from pipeline.geometry import quarter_turn
from pipeline.layout.laminate import Laminate, across_layers
from pipeline.profiles import across, bilayer
from pipeline.profiles.calibration import CalibrationError
from pipeline.profiles.profile import load_profile

PROFILE = load_profile("generic-0.5mm")
N = PROFILE.layers


@pytest.fixture(scope="module")
def printed(tmp_path_factory):
    out = tmp_path_factory.mktemp("across")
    assert main(["calibrate", "across", "--profile", "generic-0.5mm", "-o", str(out)]) == 0
    return out


def _rows(path):
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    return list(csv.DictReader(lines))


def _layout():
    pairs = across.thickness_pairs(PROFILE.shrink_curve, N, PROFILE.thickness_mm.min,
                                   PROFILE.thickness_mm.max, c=PROFILE.curvature.across_constant)
    plates, pair_of = bilayer.strips(pairs, 2, PROFILE.bed_mm)
    return pairs, [s for plate in plates for s in plate], pair_of


def _strip_of(specimens, x, y):
    for s in specimens:
        sx, sy = s.size_xy_mm
        if s.x_mm - 1e-6 <= x <= s.x_mm + sx + 1e-6 and s.y_mm - 1e-6 <= y <= s.y_mm + sy + 1e-6:
            return s
    raise AssertionError("no strip at %g, %g" % (x, y))


def test_layers_two_and_second_last_run_along_the_strips_the_others_across(printed):
    parsed = parse((printed / "across.gcode").read_text())
    pairs, specimens, pair_of = _layout()
    # Which bed axis the strips' 60 mm side lies along.
    long_axis = 0 if specimens[0].along == "x" else 1
    assert across.layer_numbers(N) == [2, N - 1]
    for layer in range(1, N + 1):
        moves = [m for m in parsed.layer_moves(layer) if m.extruding]
        d = np.array([np.subtract(m.end[:2], m.start[:2]) for m in moves])
        along = np.abs(d[:, long_axis]).sum()
        side = np.abs(d[:, 1 - long_axis]).sum()
        longest = np.hypot(d[:, 0], d[:, 1]).max()
        if layer in (2, N - 1):
            assert along > 20 * side and longest == pytest.approx(60 - 0.48, abs=0.01), layer
        else:
            assert side > 10 * along and longest < 10.0, layer
        # Every strip prints on every layer.
        hit = {_strip_of(specimens, *m.end[:2]).id for m in moves}
        assert hit == {s.id for s in specimens}, layer
    assert pairs[0][0] == pairs[0][1] and all(b < t for b, t in pairs[1:])


def test_each_layer_prints_at_the_sum_of_the_thicknesses_below_it(printed):
    parsed = parse((printed / "across.gcode").read_text())
    pairs, specimens, pair_of = _layout()
    middle = pairs[0][0]
    for layer in range(1, N + 1):
        for m in parsed.layer_moves(layer):
            if not m.extruding:
                continue
            bottom, top = pair_of[_strip_of(specimens, *m.end[:2]).id]
            table = [middle] * N
            table[1], table[N - 2] = bottom, top
            assert m.end[2] == pytest.approx(sum(table[:layer]), abs=1e-6), (layer, bottom)
    rows = _rows(printed / "across.csv")
    assert tuple(rows[0]) == bilayer.COLUMNS and len(rows) == 2 * len(pairs)
    assert {(float(r["bottom_mm"]), float(r["top_mm"])) for r in rows} == {
        tuple(p) for p in pairs}


def _laminate_curl(bottom, top, middle, c, c_across):
    """The strip as the plan's laminate models it: curvature along its length (1/mm) and
    printed thickness. d, the direction its layers along print, is the strip's width."""
    t = np.full(N, middle)
    t[1], t[N - 2] = bottom, top
    s = PROFILE.shrink_curve.sigma(t)
    lam = Laminate(layer_sigma=s[None, :], across=across_layers(N),
                   thickness_mm=np.array([t.sum()]))
    d = np.array([[0.0, 1.0]])
    length = quarter_turn(d)[0]
    K = lam.curvature(d, c=c, c_across=c_across)[0]
    return float(length @ K @ length), float(t.sum()), float(d[0] @ K @ d[0])


def test_the_strip_curls_by_the_laminate_as_the_fit_inverts_it():
    """The laminate of a strip (layers 2 and N-1 across d) curls along its length by
    c_across * lever * (s_2 - s_{N-1}) / h, whatever the constant along d, and not
    across its length: the relation the fit inverts."""
    lever = across.lever(N)
    assert lever == pytest.approx(4 * (N - 3) / N ** 2)
    for bottom, top in ((0.25, 0.3), (0.2, 0.35)):
        sb, st = PROFILE.shrink_curve.sigma(np.array([bottom, top]))
        for c_across in (1.2, 2.4):
            kappa, h, width = _laminate_curl(bottom, top, 0.275, c=9.0, c_across=c_across)
            assert h == pytest.approx(N * (bottom + top) / 2)
            assert kappa == pytest.approx(c_across * lever * (sb - st) / h, rel=1e-9)
            assert kappa > 0 and width == pytest.approx(0.0, abs=1e-12)
    assert across.lever(4) == pytest.approx(0.25) and across.lever(7) == pytest.approx(16 / 49)


def _measure(printed, c_across, tmp_path, name="across.csv"):
    """The CSV filled in as the laminate model curls each strip with ``c_across``."""
    middle = _layout()[0][0][0]
    out = []
    for ln in (printed / "across.csv").read_text().splitlines():
        cells = ln.split(",")
        if ln.startswith("#") or cells[0] == "specimen":
            out.append(ln)
            continue
        kappa, h, _ = _laminate_curl(float(cells[1]), float(cells[2]), middle, 1.5, c_across)
        if kappa:
            half = 0.5 * across.LENGTH_MM * kappa
            inside = 1 / kappa - h / 2               # the face the ruler spans
            chord, rise = 2 * inside * np.sin(half), inside * (1 - np.cos(half))
        else:
            chord, rise = across.LENGTH_MM, 0.0
        out.append(",".join(cells[:4] + ["%.3f" % chord, "%.3f" % rise]))
    path = tmp_path / name
    path.write_text("\n".join(out) + "\n")
    return path


@pytest.mark.parametrize("c_across", [0.9, 2.7])
def test_fitting_strips_curled_by_a_known_constant_recovers_it(printed, tmp_path, c_across):
    strips = bilayer.read_strips(_measure(printed, c_across, tmp_path).read_text(),
                                 kind="across")
    c, rms, pts = across.fit_c(strips, PROFILE.shrink_curve, N)
    assert c == pytest.approx(c_across, rel=0.01) and rms < 1e-4
    # The bilayer's fit of the same strips misses by the lever.
    c_bilayer = bilayer.fit_c(strips, PROFILE.shrink_curve, N)[0]
    assert c_bilayer == pytest.approx(c_across * across.lever(N), rel=0.01)


def test_across_fit_writes_a_copy_with_the_measured_constant(printed, tmp_path, capsys):
    original = tmp_path / "mine.yaml"
    original.write_text(open(PROFILE.source).read())
    before = original.read_bytes()
    measured = _measure(printed, 2.1, tmp_path)
    new = tmp_path / "mine-across.yaml"
    assert main(["calibrate", "across-fit", str(measured), "--profile", str(original),
                 "-o", str(new)]) == 0
    out = capsys.readouterr().out
    assert "constant of the layers across c_across = 2.1" in out and "wrote %s" % new in out
    section = yaml.safe_load(new.read_text())["curvature"]
    assert section["across_c"] == pytest.approx(2.1, rel=0.01)
    assert section["across_status"] == "measured"
    # The bilayer's constant and status stay as they were.
    assert (section["bilayer_c"], section["status"]) == (1.5, "uncalibrated")
    loaded = load_profile(str(new)).curvature
    assert loaded.across_constant == pytest.approx(2.1, rel=0.01)
    assert original.read_bytes() == before
    # Never over the original, never over a file unasked.
    assert main(["calibrate", "across-fit", str(measured), "--profile", str(original),
                 "-o", str(original)]) == 1
    assert "calibration.would_overwrite_profile" in capsys.readouterr().err
    assert main(["calibrate", "across-fit", str(measured), "--profile", str(original),
                 "-o", str(new)]) == 1
    assert "calibration.would_overwrite" in capsys.readouterr().err
    assert original.read_bytes() == before


def _fit_error(tmp_path, capsys, text):
    (tmp_path / "bad.csv").write_text(text)
    out = tmp_path / "x.yaml"
    assert main(["calibrate", "across-fit", str(tmp_path / "bad.csv"), "--profile",
                 "generic-0.5mm", "-o", str(out)]) == 1
    assert not out.exists()
    return capsys.readouterr().err


HEAD = ",".join(bilayer.COLUMNS) + "\n"


@pytest.mark.parametrize("text,code", [
    ("specimen,thickness_mm\n1,0.2\n", "calibration.bad_header"),
    (HEAD + "1,0.25,0.3,1,55,six\n", "calibration.not_a_number"),
    (HEAD + "1,0.25,0.3,1,40,25\n", "calibration.bad_value"),
    (HEAD + "1,0.25,0.3,1,0,0\n", "calibration.bad_value"),
    (HEAD + "1,0.275,0.275,1,60,0\n2,0.25,0.3,1,55,6\n", "calibration.too_few"),
    (HEAD + "1,0.25,0.3,1,55,-6\n2,0.241,0.309,1,52,-9\n", "calibration.bad_fit"),
])
def test_bad_measurements_are_refused_with_their_code(tmp_path, capsys, text, code):
    err = _fit_error(tmp_path, capsys, text)
    assert "[%s]" % code in err
    if code == "calibration.bad_header":
        assert "across.csv written by `hostd calibrate across`" in err


def test_a_profile_of_three_layers_has_no_layers_across(tmp_path, capsys):
    with pytest.raises(CalibrationError) as e:
        across.lever(3)
    assert e.value.code == "calibration.layers"
    data = yaml.safe_load(open(PROFILE.source).read())
    data["layers"] = 3
    (tmp_path / "three.yaml").write_text(yaml.safe_dump(data))
    assert main(["calibrate", "across", "--profile", str(tmp_path / "three.yaml"), "-o",
                 str(tmp_path / "out")]) == 1
    assert "calibration.layers" in capsys.readouterr().err


def test_a_filled_in_csv_is_not_overwritten(printed, tmp_path, capsys):
    out = tmp_path / "again"
    out.mkdir()
    (out / "across.csv").write_text(_measure(printed, 2.0, tmp_path).read_text())
    assert main(["calibrate", "across", "--profile", "generic-0.5mm", "-o", str(out)]) == 1
    assert "calibration.would_overwrite" in capsys.readouterr().err


def test_shipped_profiles_leave_the_constant_across_to_the_bilayers():
    for name in ("generic-0.5mm", "prusa-mk3s-0.4mm"):
        cp = load_profile(name).curvature
        assert cp.across_c is None and cp.across_status == "uncalibrated"
        assert cp.across_constant == cp.bilayer_c
