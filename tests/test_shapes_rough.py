"""The rough generated terrain has relief at several scales, as real tiles do."""

import numpy as np

from pipeline.input import shapes


def _band_power(z, pixel_mm, lo_mm, hi_mm):
    """Share of the field's spectral power at wavelengths between lo_mm and hi_mm."""
    w = np.hanning(z.shape[0])  # no leakage from the tile's edges into the short bands
    f = np.abs(np.fft.fft2((z - z.mean()) * np.outer(w, w))) ** 2
    k = np.fft.fftfreq(z.shape[0], d=pixel_mm)
    wavelength = 1.0 / np.maximum(np.hypot(*np.meshgrid(k, k)), 1e-9)
    return f[(wavelength >= lo_mm) & (wavelength < hi_mm)].sum() / f.sum()


def test_rough_terrain_is_repeatable_and_sized():
    a, b = shapes.rough_terrain(seed=3), shapes.rough_terrain(seed=3)
    assert np.array_equal(a.z, b.z)
    assert a.z.shape == (351, 351)
    assert np.nanmin(a.z) == 0.0 and np.isclose(np.nanmax(a.z), 30.0)
    assert not np.array_equal(a.z, shapes.rough_terrain(seed=4).z)


def test_rough_terrain_has_detail_at_several_scales():
    hf = shapes.rough_terrain()
    # Smooth hills put next to all their power above 30 mm; this tile keeps some in
    # each band down to a few millimetres.
    for lo, hi in ((12.0, 30.0), (5.0, 12.0), (2.0, 5.0)):
        assert _band_power(hf.z, hf.pixel_mm, lo, hi) > 1e-4, (lo, hi)
    smooth = shapes.terrain_tile(width_mm=175.0, depth_mm=175.0)
    assert _band_power(hf.z, hf.pixel_mm, 2.0, 12.0) > 20 * _band_power(smooth.z, smooth.pixel_mm, 2.0, 12.0)
