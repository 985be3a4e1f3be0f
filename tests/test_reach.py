"""The stack's curvature reach: how far the target bends against the most the layers'
shrink can curl a sheet of the planned thickness."""

import numpy as np
import pytest

from pipeline.geometry import HeightField
from pipeline.input import shapes
from pipeline.layout.free import flatten_free
from pipeline.layout.reach import WITHIN, curvature_limit, reach, reach_ratio
from pipeline.meshing.grid import build_grid_mesh
from pipeline.profiles.profile import load_profile
from pipeline.simulation.shell import thickness_for

PROFILE = load_profile("generic-0.5mm")
LIM = PROFILE.shrink_limits


def _reach(hf):
    mesh = build_grid_mesh(hf, PROFILE.mesh.grid_mm)
    flat = flatten_free(mesh, LIM.s_min, LIM.s_max, iterations=100)
    return reach(hf, mesh, flat, PROFILE), flat


def test_the_limit_is_a_bilayer_of_the_whole_shrink_range():
    h = np.array([1.0, 2.0])
    limit = curvature_limit(h, 0.0, 0.3, 1.5)
    assert limit == pytest.approx([0.45, 0.225])
    # A saddle bends as far as a dome of the same radius: the larger principal curvature.
    K = np.array([np.diag([0.1, -0.2]), np.diag([0.05, 0.05])])
    assert reach_ratio(K, h, 0.0, 0.3, 1.5) == pytest.approx([0.2 / 0.45, 0.05 / 0.225])


def test_a_dome_is_within_reach_at_the_curvature_of_its_sphere():
    hf = shapes.dome(diameter_mm=100.0, height_mm=20.0)
    r, flat = _reach(hf)
    radius = shapes.dome_radius_mm(100.0, 20.0)
    h = thickness_for(np.clip(flat.sigma, LIM.s_min, LIM.s_max), PROFILE.shrink_curve,
                      PROFILE.layers, PROFILE.thickness_mm.min, PROFILE.thickness_mm.max)
    expected = (1.0 / radius) / curvature_limit(h, LIM.s_min, LIM.s_max,
                                                PROFILE.curvature.bilayer_c)
    assert r["p50"] == pytest.approx(float(np.median(expected)), rel=0.1)
    assert r["within"] and r["beyond_fraction"] == 0.0


def _ribs(amplitude_mm, wavelength_mm=6.0, px=0.5):
    n = int(60 / px) + 1
    y, x = np.mgrid[0:n, 0:n] * px
    return HeightField(amplitude_mm * np.sin(2 * np.pi * x / wavelength_mm), px, source="ribs")


def test_narrow_ribs_are_beyond_reach_and_their_reach_falls_with_their_height():
    """Ribs 6 mm apart bend at ``a (2 pi / 6)^2``: 0.6 mm high they need more than the
    stack can curl, and lowering them lowers the need only in proportion."""
    high, _ = _reach(_ribs(0.6))
    low, _ = _reach(_ribs(0.3))
    assert not high["within"] and high["p90"] > 1.0 and high["beyond_fraction"] > 0.3
    assert low["p90"] == pytest.approx(high["p90"] / 2, rel=0.15)
    wide, _ = _reach(_ribs(0.6, wavelength_mm=24.0))
    assert wide["p90"] <= WITHIN
