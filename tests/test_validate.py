"""Validity: disk topology, depression filling (checked against a plain priority-flood), bed fit."""

import heapq

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from pipeline.input import shapes
from pipeline.errors import InvalidHeightField, PlanError
from pipeline.geometry import HeightField
from pipeline.input.heightfield import load
from pipeline.profiles.profile import load_profile
from pipeline.input.validate import Grid, check_fits_bed, fill_depressions, validate

PX = 0.5


def _grid(n=161):
    y, x = np.mgrid[0:n, 0:n]
    c = (n - 1) / 2
    return x - c, c - y  # pixels, +y north


def _mesa(n=161, top=20.0):
    """Flat top of height ``top`` for r < 30 px, sloping to 0 at r = 70 px; NaN beyond."""
    x, y = _grid(n)
    r = np.hypot(x, y)
    z = np.where(r < 30, top, top * (70 - r) / 40)
    z[r > 70] = np.nan
    return z


def _add_pit(z, cx, cy, radius, depth):
    """Conical pit centred on grid point (cx, cy) px (from the centre), depth at its centre."""
    x, y = _grid(z.shape[0])
    d = np.hypot(x - cx, y - cy)
    z[d < radius] -= depth * (1 - d[d < radius] / radius)
    return z


def _priority_flood(z):
    """Reference: the textbook heap priority-flood (8-neighbour), slow but obvious."""
    fp = np.isfinite(z)
    rows, cols = z.shape
    out = np.where(fp, np.inf, np.nan)
    heap, seen = [], np.zeros(z.shape, bool)
    pad = np.pad(fp, 1)
    for r, c in zip(*np.nonzero(fp)):
        if not pad[r:r + 3, c:c + 3].all():
            heapq.heappush(heap, (z[r, c], r, c))
            seen[r, c] = True
            out[r, c] = z[r, c]
    while heap:
        v, r, c = heapq.heappop(heap)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if 0 <= rr < rows and 0 <= cc < cols and fp[rr, cc] and not seen[rr, cc]:
                    seen[rr, cc] = True
                    out[rr, cc] = max(z[rr, cc], v)
                    heapq.heappush(heap, (out[rr, cc], rr, cc))
    return out


def _drains(z):
    """Per footprint cell: has a strictly lower neighbour or touches the outside."""
    fp = np.isfinite(z)
    g = Grid(fp)
    v = z[fp]
    vn = g.neighbour_values(v)
    return (vn < v[:, None]).any(axis=1) | g.boundary


# ------------------------------------------------------------------ topology

def test_two_pieces_are_disconnected():
    x, y = _grid(161)
    z = np.where((np.hypot(x + 40, y) < 30) | (np.hypot(x - 45, y) < 25), 10.0, np.nan)
    z += 0.01 * x  # not flat
    with pytest.raises(InvalidHeightField) as e:
        validate(HeightField(z, PX, source="two.npy"), 2.0)
    assert e.value.code == "validate.disconnected"
    assert e.value.details["pieces"] == 2
    assert e.value.file == "two.npy"
    # Largest piece first, centre in mm: the left disk is centred 40 px left of the middle.
    cx, cy = e.value.details["centres_mm"][0]
    assert cx == pytest.approx(40 * PX, abs=PX) and cy == pytest.approx(80 * PX, abs=PX)


def test_pieces_touching_at_a_corner_are_disconnected():
    z = np.full((40, 40), np.nan)
    z[:20, :20] = 1.0
    z[20:, 20:] = 2.0
    z[5, 5] = 3.0
    with pytest.raises(InvalidHeightField) as e:
        validate(HeightField(z, PX), 2.0)
    assert e.value.code == "validate.disconnected"


def test_interior_hole():
    z = _mesa()
    x, y = _grid()
    z[np.hypot(x - 10, y + 5) < 4] = np.nan
    with pytest.raises(InvalidHeightField) as e:
        validate(HeightField(z, PX), 2.0)
    assert e.value.code == "validate.holes"
    assert e.value.details["holes"] == 1
    hx, hy = e.value.details["centres_mm"][0]
    assert hx == pytest.approx((80 + 10) * PX, abs=PX) and hy == pytest.approx((80 - 5) * PX, abs=PX)
    assert "x=" in e.value.where


def test_notch_open_to_the_edge_is_not_a_hole():
    z = _mesa()
    z[78:83, 100:] = np.nan  # a slot from the edge inward
    validate(HeightField(z, PX), 2.0)


# ------------------------------------------------------------------ depressions

def test_fill_matches_priority_flood():
    rng = np.random.default_rng(7)
    for t in range(12):
        n = int(rng.integers(12, 45))
        z = gaussian_filter(rng.random((n, n + 5)), rng.uniform(0.7, 3)) * 10
        if t % 3 == 0:
            z = np.round(z, 1)  # plateaus and ties
        if t % 2 == 0:
            x, y = np.meshgrid(np.arange(n + 5) - (n + 4) / 2, np.arange(n) - (n - 1) / 2)
            z[np.hypot(x, y) > n / 2.1] = np.nan
        filled, info = fill_depressions(z)
        fp = np.isfinite(z)
        np.testing.assert_allclose(info["exact"], _priority_flood(z)[fp], rtol=0, atol=1e-12)
        # Epsilon slope: every filled cell drains strictly, and the raise stays tiny.
        assert info["unresolved"] == 0
        changed = info["exact"] > z[fp]
        assert _drains(filled)[changed].all()
        assert 0 <= (filled[fp] - info["exact"]).min() and (filled[fp] - info["exact"]).max() < 0.05


def test_crater_deeper_than_max_fill_is_rejected_with_location():
    z = _add_pit(_mesa(), cx=-12, cy=9, radius=10, depth=6.0)
    with pytest.raises(InvalidHeightField) as e:
        validate(HeightField(z, PX, source="crater.npy"), max_fill_mm=2.0)
    err = e.value
    assert err.code == "validate.depression"
    assert "sidecar crater.yaml" in err.fix and "`max_fill_mm: 6.1`" in err.fix
    dep = err.details["depressions"][0]
    assert dep["depth_mm"] == pytest.approx(6.0, abs=1e-9)
    assert dep["x_mm"] == pytest.approx((80 - 12) * PX, abs=PX)
    assert dep["y_mm"] == pytest.approx((80 + 9) * PX, abs=PX)
    assert "max_fill_mm" in err.fix
    # The same crater is filled when the limit allows it.
    out, rep = validate(HeightField(z, PX), max_fill_mm=6.5)
    assert rep["filled_pits"] == 1 and rep["deepest_fill_mm"] == pytest.approx(6.0)


def test_shallow_pits_filled_count_volume_depth():
    z0 = _mesa()
    z = z0.copy()
    for (cx, cy, r, d) in [(-15, 0, 6, 0.5), (10, 12, 8, 1.0), (12, -14, 7, 1.5)]:
        z = _add_pit(z, cx, cy, r, d)
    out, rep = validate(HeightField(z, PX), max_fill_mm=2.0)
    assert rep["filled_pits"] == 3
    assert rep["deepest_fill_mm"] == pytest.approx(1.5)
    fp = np.isfinite(z)
    assert rep["filled_volume_mm3"] == pytest.approx(np.sum(z0[fp] - z[fp]) * PX * PX, rel=1e-9)
    depths = sorted(p["depth_mm"] for p in rep["filled"])
    assert depths == pytest.approx([0.5, 1.0, 1.5])
    # Filled, but not flat: every filled cell has a strictly lower neighbour.
    filled = out.z[fp] > z[fp]
    assert _drains(out.z)[filled].all()
    assert np.ptp(out.z[fp][z0[fp] - z[fp] > 0]) > 0
    assert np.all(out.z[fp] - z0[fp] < 0.02) and np.all(out.z[fp] >= z0[fp])
    assert rep["unresolved_flat_cells"] == 0


def test_valley_open_to_the_edge_is_not_filled():
    z = _mesa()
    x, y = _grid()
    z -= 5 * np.exp(-(y / 4) ** 2) * (x > 0)  # a trench running out to the east edge
    out, rep = validate(HeightField(z, PX), max_fill_mm=0.1)
    assert rep["filled_pits"] == 0
    np.testing.assert_array_equal(out.z, z)


def test_report_on_a_dome():
    hf = shapes.dome(diameter_mm=120, height_mm=25, pixel_mm=0.5)
    out, rep = validate(hf, 2.0)
    assert rep["filled_pits"] == 0 and rep["filled_volume_mm3"] == 0
    assert rep["longest_diameter_mm"] == pytest.approx(120, abs=1.0)
    assert rep["max_height_mm"] == pytest.approx(25, abs=1e-6)


# ------------------------------------------------------------------ bed

def test_check_fits_bed():
    assert check_fits_bed((200, 100), (220, 220))["margin_mm"] == pytest.approx(20)
    assert check_fits_bed((240, 200), (250, 210)) == {"rotated": False, "margin_mm": 10.0}
    assert check_fits_bed((200, 240), (250, 210))["rotated"] is True
    with pytest.raises(PlanError) as e:
        check_fits_bed((260, 100), (250, 210), allow_rotation=False)
    assert e.value.code == "validate.too_large"
    assert e.value.details["overhang_mm"] == pytest.approx(10)
    with pytest.raises(PlanError) as e:
        check_fits_bed((300, 230), (250, 210))
    assert e.value.details["overhang_mm"] == pytest.approx(min(50, 80))


def test_validate_checks_footprint_against_bed():
    hf = shapes.dome(diameter_mm=120, height_mm=25)
    validate(hf, 2.0, bed_mm=(125, 125))
    with pytest.raises(PlanError) as e:
        validate(hf, 2.0, bed_mm=(100, 150))
    assert e.value.code == "validate.too_large"


# ------------------------------------------------------------------ real terrain

@pytest.mark.parametrize("name", ["vancouver_island_south", "coast_mountains_bc"])
def test_real_terrain_validates_with_its_sidecar(terrain_dir, name):
    profile = load_profile("generic-0.5mm")
    hf, sc = load(terrain_dir / (name + ".png"), profile)
    out, rep = validate(hf, sc.max_fill_mm, bed_mm=profile.bed_mm)
    # README: real closed depressions 4.5-5.1 mm deep at this scale.
    assert 4.4 < rep["deepest_fill_mm"] <= sc.max_fill_mm
    assert rep["filled_pits"] > 10 and rep["unresolved_flat_cells"] == 0
    fp = hf.footprint
    changed = out.z[fp] > hf.z[fp]
    assert _drains(out.z)[changed].all()
    # With the profile's default 2 mm the deep ones are refused.
    with pytest.raises(InvalidHeightField) as e:
        validate(hf, profile.validate.max_fill_mm)
    assert e.value.code == "validate.depression"
    assert e.value.details["depressions"][0]["depth_mm"] == pytest.approx(rep["deepest_fill_mm"])
