"""Bilayer calibration: strips printed with a thickness difference through them, their
measured curl fitted to the bilayer constant, which the plan then uses."""

import csv
import dataclasses

import numpy as np
import pytest
import yaml

from gcode_parser import parse
from hostd.cli import main
from pipeline.input import shapes
from pipeline.layout import curvature
from pipeline.profiles import bilayer
from pipeline.profiles.profile import load_profile

PROFILE = load_profile("generic-0.5mm")


@pytest.fixture(scope="module")
def printed(tmp_path_factory):
    out = tmp_path_factory.mktemp("bilayer")
    assert main(["calibrate", "bilayer", "--profile", "generic-0.5mm", "-o", str(out)]) == 0
    return out


def test_strips_print_their_lower_layers_thinner_than_their_upper_ones(printed):
    parsed = parse((printed / "bilayer.gcode").read_text())
    pairs = bilayer.thickness_pairs(PROFILE.shrink_curve, PROFILE.layers,
                                    PROFILE.thickness_mm.min, PROFILE.thickness_mm.max)
    # The layer heights each strip prints at, lowest first: each strip's steps.
    tops = []
    for layer in range(1, PROFILE.layers + 1):
        zs = sorted({round(m.end[2], 3) for m in parsed.layer_moves(layer) if m.extruding})
        tops.append(zs)
    half = PROFILE.layers // 2
    for bottom, top in pairs:
        # Its Z after the lower half is half * bottom; the top layers add `top` each.
        z_low = round(half * bottom, 3)
        z_all = round(half * (bottom + top), 3)
        assert z_low in tops[half - 1] and z_all in tops[-1], (bottom, top)
    assert pairs[0][0] == pairs[0][1] and any(b < t for b, t in pairs)
    rows = list(csv.reader(ln for ln in (printed / "bilayer.csv").read_text().splitlines()
                           if not ln.startswith("#")))
    assert tuple(rows[0]) == bilayer.COLUMNS and len(rows) - 1 == 2 * len(pairs)


def _measure(printed, c, tmp_path):
    """The CSV filled in as strips of bilayer constant ``c`` would curl, 60 mm long."""
    lines = (printed / "bilayer.csv").read_text().splitlines()
    out = []
    for ln in lines:
        cells = ln.split(",")
        if ln.startswith("#") or cells[0] == "specimen":
            out.append(ln)
            continue
        b, t = float(cells[1]), float(cells[2])
        sb, st = PROFILE.shrink_curve.sigma(np.array([b, t]))
        h = PROFILE.layers * (b + t) / 2
        kappa = c * (sb - st) / h
        half = 0.5 * bilayer.LENGTH_MM * kappa
        inside = 1 / kappa - h / 2 if kappa else 0.0        # the face the ruler spans
        chord = 2 * inside * np.sin(half) if kappa else bilayer.LENGTH_MM
        rise = inside * (1 - np.cos(half)) if kappa else 0.0
        out.append(",".join(cells[:4] + ["%.3f" % chord, "%.3f" % rise]))
    path = tmp_path / "bilayer.csv"
    path.write_text("\n".join(out) + "\n")
    return path


def test_fitting_strips_that_curl_with_a_known_constant_recovers_it(printed, tmp_path):
    measured = _measure(printed, 2.1, tmp_path)
    new = tmp_path / "mine.yaml"
    assert main(["calibrate", "bilayer-fit", str(measured), "--profile", "generic-0.5mm",
                 "-o", str(new)]) == 0
    section = yaml.safe_load(new.read_text())["curvature"]
    assert section["bilayer_c"] == pytest.approx(2.1, rel=0.01)
    assert section["status"] == "measured"
    assert load_profile(str(new)).curvature.bilayer_c == pytest.approx(2.1, rel=0.01)


def test_only_flat_strips_measured_is_refused(printed, tmp_path, capsys):
    lines = [ln for ln in _measure(printed, 2.1, tmp_path).read_text().splitlines()
             if ln.startswith("#") or ln.startswith("specimen") or ",0.275,0.275," in ln]
    (tmp_path / "flat.csv").write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "bilayer-fit", str(tmp_path / "flat.csv"), "--profile",
                 "generic-0.5mm", "-o", str(tmp_path / "x.yaml")]) == 1
    assert "calibration.too_few" in capsys.readouterr().err
    assert not (tmp_path / "x.yaml").exists()


def test_shipped_profiles_carry_an_uncalibrated_constant_and_the_plan_uses_the_profiles():
    assert PROFILE.curvature.status == "uncalibrated"
    assert PROFILE.curvature.bilayer_c == curvature.BILAYER_C
    hf = shapes.dome(60.0, 12.0)
    from hostd import planner
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as tmp:
        np.save(Path(tmp) / "d.npy", hf.z)
        (Path(tmp) / "d.yaml").write_text("pixel_mm: %r\nmethod: free\n" % hf.pixel_mm)
        plans = {}
        for c in (1.5, 3.0):
            # Along d only: whether the outer layers print across is the sheet's choice.
            prof = dataclasses.replace(PROFILE, curvature=dataclasses.replace(
                PROFILE.curvature, bilayer_c=c, across_layers="off"))
            plans[c] = planner.run(Path(tmp) / "d.npy", prof, Path(tmp) / ("o%g" % c))
    # Twice the constant: half the thickness difference for the same curvature.
    d1, d3 = (np.abs(plans[c].curvature.delta_sigma).max() for c in (1.5, 3.0))
    assert d3 == pytest.approx(d1 / 2, rel=0.05)
    assert plans[3.0].report["curvature"]["bilayer_c"] == 3.0


def test_a_strip_curled_the_other_way_has_a_negative_curvature():
    up = bilayer.Strip("1", 0.25, 0.3, 50.0, 5.0)
    down = bilayer.Strip("2", 0.25, 0.3, 50.0, -5.0)
    assert up.curvature(6) > 0 and down.curvature(6) == pytest.approx(-up.curvature(6))
    # The middle surface lies half the printed thickness (6 x 0.275 / 2) outside the face.
    assert 1 / up.curvature(6) == pytest.approx((50.0 ** 2 + 4 * 25) / 40 + 0.825)
