"""Synthetic reference shapes, generated in code (like the paper's five models).

Each function returns a :class:`pipeline.geometry.HeightField` with NaN outside
the footprint. Sizes follow the paper's Table 1 (longest diameters ~150-180 mm,
heights ~25-40 mm) unless given.
"""

import numpy as np

from pipeline.geometry import HeightField


def _grid(size_mm, pixel_mm):
    n = int(round(size_mm / pixel_mm)) + 1
    c = (np.arange(n) - (n - 1) / 2.0) * pixel_mm
    x, y = np.meshgrid(c, -c)  # row 0 = north (+y)
    return x, y


def dome(diameter_mm=120.0, height_mm=25.0, pixel_mm=0.5):
    """Spherical cap of footprint ``diameter_mm`` and apex ``height_mm``.

    The sphere radius is ``rho = (R^2 + H^2) / (2 H)`` for footprint radius R.
    """
    R, H = diameter_mm / 2.0, height_mm
    rho = (R * R + H * H) / (2 * H)
    x, y = _grid(diameter_mm + 4 * pixel_mm, pixel_mm)
    r2 = x * x + y * y
    z = np.sqrt(np.maximum(rho * rho - r2, 0)) - (rho - H)
    z[r2 > R * R] = np.nan
    return HeightField(np.maximum(z, 0.0), pixel_mm, source="dome")


def dome_radius_mm(diameter_mm=120.0, height_mm=25.0):
    """Sphere radius rho of :func:`dome` with these arguments (for analytic checks)."""
    R, H = diameter_mm / 2.0, height_mm
    return (R * R + H * H) / (2 * H)


def elongated_peak(length_mm=160.0, width_mm=90.0, height_mm=30.0, pixel_mm=0.5):
    """Asymmetric elongated peak on an elliptic footprint, summit off centre."""
    a, b = length_mm / 2.0, width_mm / 2.0
    x, y = _grid(length_mm + 4 * pixel_mm, pixel_mm)
    q = (x / a) ** 2 + (y / b) ** 2
    inside = q <= 1.0
    # Summit shifted along the long axis; taper keeps height 0 on the boundary.
    bump = np.exp(-(((x - 0.3 * a) / (0.55 * a)) ** 2 + (y / (0.6 * b)) ** 2))
    z = bump * (1.0 - q)
    z = np.where(inside, z, np.nan)
    z *= height_mm / np.nanmax(z)
    return HeightField(z, pixel_mm, source="elongated_peak")


def three_islands(diameter_mm=150.0, height_mm=34.0, pixel_mm=0.5):
    """Three peaks of different heights on one base, joined by saddles."""
    R = diameter_mm / 2.0
    x, y = _grid(diameter_mm + 4 * pixel_mm, pixel_mm)
    r2 = x * x + y * y
    peaks = [(-0.38 * R, 0.25 * R, 1.0, 0.22 * R), (0.4 * R, 0.2 * R, 0.8, 0.2 * R),
             (0.0, -0.45 * R, 0.65, 0.2 * R)]
    z = 0.25 * np.ones_like(x)
    for px, py, h, s in peaks:
        z = z + h * np.exp(-((x - px) ** 2 + (y - py) ** 2) / (2 * s * s))
    z = z * (1.0 - r2 / (R * R))
    z = np.where(r2 <= R * R, z, np.nan)
    z *= height_mm / np.nanmax(z)
    return HeightField(z, pixel_mm, source="three_islands")


def saddle(length_mm=150.0, width_mm=110.0, height_mm=30.0, pixel_mm=0.5):
    """Two peaks joined by one saddle on an elliptic footprint."""
    a, b = length_mm / 2.0, width_mm / 2.0
    x, y = _grid(length_mm + 4 * pixel_mm, pixel_mm)
    q = (x / a) ** 2 + (y / b) ** 2
    s = 0.3 * a
    z = (np.exp(-((x + 0.42 * a) ** 2 + y ** 2) / (2 * s * s))
         + 0.85 * np.exp(-((x - 0.42 * a) ** 2 + y ** 2) / (2 * s * s)) + 0.3) * (1.0 - q)
    z = np.where(q <= 1.0, z, np.nan)
    z *= height_mm / np.nanmax(z)
    return HeightField(z, pixel_mm, source="saddle")


def starfish(diameter_mm=175.0, height_mm=33.4, arms=5, pixel_mm=0.5):
    """Starfish-like: a five-armed, non-convex footprint over a domed body.

    The surface is a spherical cap (positive curvature everywhere, so every
    printing edge can reach its length by shrinking) cut by the star outline:
    the arm tips sit lowest, the edge between arms higher, so isolines are
    open arcs across the arms and loops over the body. Sizes as the paper's
    starfish (Table 1: 175.2 mm, 33.4 mm).
    """
    R = diameter_mm / 2.0
    x, y = _grid(diameter_mm + 4 * pixel_mm, pixel_mm)
    r = np.hypot(x, y)
    phi = np.arctan2(y, x)
    # Arms where cos(arms*phi/2) = +-1; the power narrows them into arms.
    rb = R * (0.42 + 0.58 * np.abs(np.cos(arms * phi / 2.0)) ** 3)
    rho = (R * R + height_mm ** 2) / (2 * height_mm)
    z = np.sqrt(np.maximum(rho * rho - r * r, 0.0)) - (rho - height_mm)
    z = np.where(r <= rb, np.maximum(z, 0.0), np.nan)
    return HeightField(z, pixel_mm, source="starfish")


def starfish_ridged(diameter_mm=175.0, height_mm=33.0, arms=5, pixel_mm=0.5):
    """A starfish whose arms are ridges falling to a level edge.

    The valleys between the arms curve negatively (half the area), which
    shrinking alone cannot form: a stress case for the invalid-edge report,
    not a reference shape.
    """
    R = diameter_mm / 2.0
    x, y = _grid(diameter_mm + 4 * pixel_mm, pixel_mm)
    r = np.hypot(x, y)
    phi = np.arctan2(y, x)
    rb = R * (0.42 + 0.58 * np.abs(np.cos(arms * phi / 2.0)) ** 3)
    t = r / rb
    z = (1.0 - t ** 2) * (1.0 - 0.5 * t)
    z = np.where(t <= 1.0, z, np.nan)
    z *= height_mm / np.nanmax(z)
    return HeightField(z, pixel_mm, source="starfish_ridged")


def terrain_tile(width_mm=120.0, depth_mm=90.0, height_mm=25.0, pixel_mm=0.5, seed=7):
    """A rectangular tile 'cut from a map': its edge is not at one height.

    Smooth random hills (a few Gaussians) with no closed depressions deeper
    than a fraction of a millimetre, so isolines end on the boundary as arcs.
    """
    rng = np.random.default_rng(seed)
    nx = int(round(width_mm / pixel_mm)) + 1
    ny = int(round(depth_mm / pixel_mm)) + 1
    x, y = np.meshgrid(np.arange(nx) * pixel_mm, (ny - 1 - np.arange(ny)) * pixel_mm)
    z = 0.15 * x + 0.1 * y  # a regional slope so the edge heights vary
    for _ in range(4):
        cx, cy = rng.uniform(0.2, 0.8) * width_mm, rng.uniform(0.2, 0.8) * depth_mm
        s = rng.uniform(0.15, 0.25) * min(width_mm, depth_mm)
        z = z + rng.uniform(0.5, 1.0) * 20 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * s * s))
    z -= z.min()
    z *= height_mm / z.max()
    return HeightField(z, pixel_mm, source="terrain_tile")


def _disk_field(diameter_mm, pixel_mm, f, height_mm, source):
    """``f(u, v)`` on the unit disk, scaled to ``height_mm`` of relief above its lowest point."""
    n = int(round(diameter_mm / pixel_mm)) + 1
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(1, -1, n))
    z = f(u, v)
    inside = u * u + v * v <= 1.0
    z = z - z[inside].min()
    z = np.where(inside, z * height_mm / z[inside].max(), np.nan)
    return HeightField(z, (diameter_mm) / (n - 1), source=source)


def hyperbolic_paraboloid(diameter_mm=120.0, height_mm=30.0, pixel_mm=0.5):
    """z ~ x^2 - y^2 on a disk: negative curvature everywhere, the paper's model cannot form it."""
    return _disk_field(diameter_mm, pixel_mm, lambda u, v: u * u - v * v, height_mm,
                       "hyperbolic_paraboloid")


def monkey_saddle(diameter_mm=136.0, height_mm=22.0, pixel_mm=0.5):
    """z ~ x^3 - 3 x y^2 on a disk: three valleys and three ridges around a flat point."""
    return _disk_field(diameter_mm, pixel_mm, lambda u, v: u ** 3 - 3 * u * v * v, height_mm,
                       "monkey_saddle")


def _band_noise(rng, n, wavelength_px):
    """(n, n) noise of unit std whose features are about ``wavelength_px`` across."""
    k = np.fft.fftfreq(n)
    kk = np.hypot(*np.meshgrid(k, k))
    f0 = 1.0 / wavelength_px
    band = np.exp(-0.5 * ((kk - f0) / (0.35 * f0)) ** 2)
    field = np.fft.ifft2(np.fft.fft2(rng.standard_normal((n, n))) * band).real
    return field / field.std()


def rough_terrain(size_mm=175.0, height_mm=30.0, pixel_mm=0.5, seed=3):
    """A square tile of ridged terrain with detail at several scales, not smooth hills.

    Broad masses (90 mm) carry ridged noise (``(1 - |n|)^2``: sharp crests, rounded
    valleys) at wavelengths of 40, 16, 7 and 3 mm, each octave fainter and, as in real
    relief, stronger where the larger ones stand high; a regional slope so the edge is not
    at one height.
    """
    rng = np.random.default_rng(seed)
    n = int(round(size_mm / pixel_mm)) + 1
    mass = _band_noise(rng, n, 90.0 / pixel_mm)  # mountain masses and basins
    z = 1.2 * mass
    weight = np.clip(0.6 + 0.4 * mass, 0.1, 1.0)
    for wavelength_mm, amp in ((40.0, 1.0), (16.0, 0.45), (7.0, 0.2), (3.0, 0.08)):
        ridge = (1.0 - np.abs(_band_noise(rng, n, wavelength_mm / pixel_mm))) ** 2
        z += amp * weight * ridge
        weight = np.clip(weight * (0.4 + 0.6 * ridge), 0.05, 1.0)
    x, y = np.meshgrid(np.arange(n), np.arange(n)[::-1])
    z += 0.3 * (x + 0.5 * y) / n
    z -= z.min()
    z *= height_mm / z.max()
    return HeightField(z, pixel_mm, source="rough_terrain")


REFERENCE = {"dome": dome, "elongated_peak": elongated_peak, "saddle": saddle,
             "three_islands": three_islands, "starfish": starfish, "terrain_tile": terrain_tile}
STRESS = {"starfish_ridged": starfish_ridged}
# Real-like relief: ridges and valleys at several scales (planned with the fit).
TERRAIN = {"rough_terrain": rough_terrain}
# Negatively curved shapes the free-direction layout forms and the paper's cannot.
SADDLES = {"hyperbolic_paraboloid": hyperbolic_paraboloid, "monkey_saddle": monkey_saddle}
