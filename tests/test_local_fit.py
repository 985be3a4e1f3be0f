"""The local fit smooths only where the sheet cannot form the input, blended, and keeps
the input as given elsewhere."""

import numpy as np
import pytest

from pipeline.geometry import HeightField
from pipeline.input.simplify import smooth
from pipeline.layout import local
from pipeline.profiles.profile import load_profile

PROFILE = load_profile("generic-0.5mm")


def _hill_with_a_spike(px=0.5, size_mm=80.0):
    """A broad gentle hill, and at (20, 40) mm a spike 2 mm across the sheet cannot curl
    into: (HeightField)."""
    n = int(size_mm / px) + 1
    y, x = np.mgrid[0:n, 0:n] * px
    hill = 8.0 * np.exp(-((x - 50) ** 2 + (y - 40) ** 2) / (2 * 15.0 ** 2))
    spike = 3.0 * np.exp(-((x - 20) ** 2 + (y - 40) ** 2) / (2 * 1.0 ** 2))
    return HeightField(hill + spike, px, source="spike")


def test_the_limits_are_the_shrink_ranges_slope_and_a_share_of_the_stacks_curl():
    slope, k = local.limits(PROFILE)
    lim = PROFILE.shrink_limits
    assert slope == pytest.approx(np.tan(np.arccos(1 - lim.s_max)))
    assert 0.01 < k < 1.0


def test_a_spike_is_smoothed_where_it_stands_and_the_hill_kept_as_given():
    hf = _hill_with_a_spike()
    fit = local.LocalFit(hf, *local.limits(PROFILE))
    assert 0 < fit.beyond_share() < 0.1
    out = fit.at(8.0)
    moved = local.removed(hf, out)
    y, x = np.mgrid[0:hf.z.shape[0], 0:hf.z.shape[1]] * hf.pixel_mm
    near_spike = np.hypot(x - 20, y - 40) < 3
    far = np.hypot(x - 20, y - 40) > 15
    assert moved[near_spike].max() > 1.5            # the spike is gone
    assert moved[far].max() < 1e-6                  # the hill is the input as given
    # A global smoothing that removes the spike moves the hill too.
    glob = smooth(hf.z, 4.0 / hf.pixel_mm)
    assert np.abs(glob - hf.z)[far].max() > 0.05


def test_the_smoothing_is_blended_without_a_seam():
    hf = _hill_with_a_spike()
    fit = local.LocalFit(hf, *local.limits(PROFILE))
    z, level = local.blended(fit.fields, fit.need, hf.pixel_mm, len(local.LADDER_MM) - 1)
    step = np.abs(np.diff(level, axis=1))
    # The level changes by at most a fraction of a ladder step from one sample to the next.
    assert np.nanmax(step) < 0.75
    assert np.nanmax(np.abs(np.diff(z, axis=1))) < 1.0


def test_the_cap_bounds_the_smoothing():
    hf = _hill_with_a_spike()
    fit = local.LocalFit(hf, *local.limits(PROFILE))
    small, large = local.removed(hf, fit.at(1.0)), local.removed(hf, fit.at(8.0))
    assert np.nanmax(small) < np.nanmax(large)
    assert np.array_equal(fit.at(0.0).z, hf.z)
