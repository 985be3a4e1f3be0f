"""Seeded random terrains for the property tests of the meshers and layouts."""

import numpy as np
from scipy.ndimage import zoom

from pipeline.geometry import HeightField


def random_terrain(seed):
    """A seeded random terrain, 60-200 mm on 81 x 81 pixels: fractal noise, ridges,
    terraces, a plateau or a cliff (by ``seed % 5``), 5-40 mm high, on a square or a
    disk. Returns HeightField."""
    rng = np.random.default_rng(seed)
    size = rng.uniform(60, 200)
    px = size / 80
    n = 81
    y, x = np.mgrid[0:n, 0:n] * px
    kind = seed % 5
    z = np.zeros((n, n))
    for octave in range(4):                                   # fractal noise
        k = 2 ** octave
        coarse = rng.normal(size=(k + 2, k + 2))
        z += zoom(coarse, n / (k + 2), order=3)[:n, :n] / k
    if kind == 1:                                             # ridges
        z = 1 - np.abs(z)
    elif kind == 2:                                           # terraces
        z = np.round(z * 4) / 4
    elif kind == 3:                                           # plateau
        z = np.minimum(z, np.percentile(z, 60))
    elif kind == 4:                                           # a cliff
        z = z + 2.0 * (x > size / 2)
    z = (z - z.min()) / max(np.ptp(z), 1e-9) * rng.uniform(5, 40)
    footprint = rng.random() < 0.5
    if footprint:
        r = np.hypot(x - size / 2, y - size / 2)
        z[r > size / 2] = np.nan
    return HeightField(z, px, source="random %d" % seed)
