"""Terrain simplification: low peaks cut to their saddles, big ones kept, no pits left."""

import numpy as np
import pytest

from pipeline.input import shapes
from pipeline.geometry import HeightField
from pipeline.input.heightfield import load
from pipeline.profiles.profile import load_profile
from pipeline.input.simplify import MAX_LISTED, interior_maxima, simplify, smooth
from pipeline.input.validate import Grid, fill_depressions, validate

PX = 0.5


def _no_pits(z):
    """True when filling changes nothing: no closed depression of any depth."""
    fp = np.isfinite(z)
    _, info = fill_depressions(z)
    return np.array_equal(info["exact"], z[fp])


def _dome_with_bump(bump_mm=1.2, at=(25.0, -12.0)):
    """Dome (apex 25 mm) with a narrow bump on its flank, well below the apex."""
    hf = shapes.dome(diameter_mm=120, height_mm=25, pixel_mm=PX)
    rows, cols = hf.z.shape
    xy = hf.xy(*np.mgrid[0:rows, 0:cols])
    centre = xy[rows // 2, cols // 2]
    d2 = ((xy - centre - np.array(at)) ** 2).sum(-1)
    z = hf.z + bump_mm * np.exp(-d2 / (2 * 1.0 ** 2))
    return HeightField(z, PX, source="bump"), centre + np.array(at)


def test_tiny_bump_on_a_dome_is_removed_and_located():
    hf, where = _dome_with_bump()
    r, c = interior_maxima(hf.z)
    assert len(r) == 2  # apex and bump
    bump_rc = [(i, j) for i, j in zip(r, c) if abs(hf.xy(i, j)[0] - where[0]) < 5][0]
    bump_xy = hf.xy(*bump_rc)
    out, rep = simplify(hf, min_prominence_mm=2.0, smooth_mm=0.0)
    assert rep["peaks_before"] == 2 and rep["peaks_after"] == 1
    assert rep["removed_count"] == 1
    (peak,) = rep["removed_peaks"]
    assert peak["x_mm"] == pytest.approx(bump_xy[0], abs=PX)
    assert peak["y_mm"] == pytest.approx(bump_xy[1], abs=PX)
    assert 0 < peak["prominence_mm"] < 1.2
    # The apex is untouched; the bump is cut by about its prominence, not more.
    apex = np.unravel_index(np.nanargmax(hf.z), hf.z.shape)
    assert out.z[apex] == pytest.approx(hf.z[apex])
    assert rep["max_change_mm"] == pytest.approx(peak["prominence_mm"], abs=0.01)
    assert _no_pits(out.z)


def test_cut_top_is_not_flat_and_makes_no_new_extrema():
    hf, _ = _dome_with_bump(bump_mm=1.8)
    out, rep = simplify(hf, 2.0, 0.0)
    fp = hf.footprint
    cut = out.z[fp] < hf.z[fp] - 1e-9
    assert cut.sum() > 20
    g = Grid(fp)
    v = out.z[fp]
    vn = g.neighbour_values(v, outside=-np.inf)
    higher = (vn > v[:, None]).any(axis=1)
    # Every cut cell still climbs somewhere (toward the saddle and the summit).
    assert higher[cut].all()
    assert np.ptp(v[cut]) > 0
    assert len(interior_maxima(out.z)[0]) == 1
    assert _no_pits(out.z)


def test_big_peaks_survive():
    hf = shapes.three_islands(pixel_mm=PX)
    out, rep = simplify(hf, min_prominence_mm=2.0, smooth_mm=1.0)
    assert rep["peaks_before"] == rep["peaks_after"] == 3
    assert rep["removed_count"] == 0
    # Broad peaks (sigma ~15 mm) barely feel a 1 mm smoothing.
    assert np.nanmax(out.z) == pytest.approx(np.nanmax(hf.z), abs=0.2)
    assert _no_pits(out.z)


def test_prominence_threshold_is_strict_and_zero_keeps_everything():
    hf, _ = _dome_with_bump()
    _, rep0 = simplify(hf, 0.0, 0.0)
    assert rep0["peaks_after"] == 2 and rep0["removed_count"] == 0
    _, rep = simplify(hf, 2.0, 0.0)
    prom = rep["removed_peaks"][0]["prominence_mm"]
    _, rep_at = simplify(hf, prom, 0.0)  # exactly as prominent as the limit: kept
    assert rep_at["peaks_after"] == 2
    _, rep_above = simplify(hf, prom * 1.01, 0.0)
    assert rep_above["peaks_after"] == 1


def test_smoothing_does_not_leak_nan_or_the_outside():
    z = np.full((60, 60), np.nan)
    y, x = np.mgrid[0:60, 0:60]
    inside = np.hypot(x - 30, y - 30) < 25
    z[inside] = 10.0
    s = smooth(z, 3.0)
    assert np.isnan(s[~inside]).all()
    np.testing.assert_allclose(s[inside], 10.0)


def test_nothing_to_do_leaves_the_field():
    hf = shapes.dome(pixel_mm=PX)
    out, rep = simplify(hf, 2.0, 0.0)
    np.testing.assert_array_equal(out.z, hf.z)
    assert rep["max_change_mm"] == 0 and rep["peaks_after"] == 1


def test_smoothing_that_closes_a_pit_is_refilled():
    # A narrow channel draining a basin: smoothing raises the channel floor into a dam.
    n = 121
    y, x = np.mgrid[0:n, 0:n]
    z = np.full((n, n), 10.0)
    z[np.hypot(x - 60, y - 60) < 20] = 2.0  # basin
    z[58:63, 60:] = 2.0  # channel to the east edge, 5 px wide
    z += 0.001 * x  # no exact ties
    hf = HeightField(z, PX)
    hf, _ = validate(hf, 2.0)
    out, rep = simplify(hf, 0.0, 2.0)
    assert rep["refill_max_mm"] > 0.01
    assert _no_pits(out.z)


@pytest.mark.parametrize("name", ["vancouver_island_south", "coast_mountains_bc"])
def test_real_terrain_simplifies(terrain_dir, name):
    profile = load_profile("generic-0.5mm")
    hf, sc = load(terrain_dir / (name + ".png"), profile)
    hf, _ = validate(hf, sc.max_fill_mm)
    out, rep = simplify(hf, profile.mesh.min_prominence_mm, profile.mesh.smooth_mm)
    assert rep["peaks_before"] > 100
    assert rep["peaks_after"] < rep["peaks_before"] / 3
    assert len(rep["removed_peaks"]) == min(MAX_LISTED, rep["removed_count"])
    proms = [p["prominence_mm"] for p in rep["removed_peaks"]]
    assert proms == sorted(proms, reverse=True) and max(proms) < 2.0
    assert rep["unresolved_flat_cells"] == 0
    assert _no_pits(out.z)
    # Simplifying again finds nothing left below the threshold.
    _, again = simplify(out, profile.mesh.min_prominence_mm, 0.0)
    assert again["removed_count"] == 0
