"""The free-direction layout: a projection that is one, domes along their isolines,
saddles the paper's method cannot form, and no height field that breaks it."""

import numpy as np
import pytest

from pipeline.errors import PipelineError
from terrains import random_terrain
from pipeline.input import shapes
from pipeline.layout.free import flatten_free, project, svd2, violation
from pipeline.meshing.grid import build_grid_mesh
from pipeline.profiles.profile import load_profile

LO, HI = 1.0, 1.0 / (1.0 - 0.34)


def _admissible(P):
    _, s, _ = svd2(P)
    return (np.all(np.linalg.det(P) > 0) and np.allclose(s[:, 1], 1.0)
            and np.all((s[:, 0] >= LO - 1e-9) & (s[:, 0] <= HI + 1e-9)))


def test_svd2_reconstructs_with_rotations():
    J = np.random.default_rng(0).normal(size=(500, 2, 2))
    U, s, V = svd2(J)
    S = np.zeros_like(J)
    S[:, 0, 0], S[:, 1, 1] = s[:, 0], s[:, 1]
    assert np.allclose(U @ S @ np.transpose(V, (0, 2, 1)), J)
    assert np.allclose(np.linalg.det(U), 1) and np.allclose(np.linalg.det(V), 1)


def test_the_projection_is_a_projection():
    rng = np.random.default_rng(1)
    J = rng.normal(scale=0.7, size=(400, 2, 2)) + np.eye(2)
    P, lam, _ = project(J, LO, HI)
    assert _admissible(P)
    P2, _, _ = project(P, LO, HI)
    assert np.allclose(P2, P)                                     # idempotent
    # Never farther than the input from the set: the input's distance to any admissible
    # matrix (here, 300 random ones) is at least its distance to P.
    d = np.linalg.norm(J - P, axis=(1, 2))
    for _ in range(300):
        a, b = rng.uniform(0, 2 * np.pi, 2)
        R = lambda t: np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
        Q = R(a) @ np.diag([rng.uniform(LO, HI), 1.0]) @ R(b)
        assert np.all(np.linalg.norm(J - Q, axis=(1, 2)) >= d - 1e-9)


def test_the_projection_matches_brute_force():
    rng = np.random.default_rng(2)
    J = rng.normal(scale=0.5, size=(20, 2, 2)) + np.eye(2)
    P, _, _ = project(J, LO, HI)
    t = np.linspace(0, 2 * np.pi, 721)
    for j, p in zip(J, P):
        # For rotations U(a), V(b) the best lambda is clamp((U^T J V)_00); search a and b.
        a, b = np.meshgrid(t, t, indexing="ij")
        ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
        # (U^T J V) entries for U = R(a), V = R(b).
        m00 = ca * (j[0, 0] * cb + j[0, 1] * sb) + sa * (j[1, 0] * cb + j[1, 1] * sb)
        m11 = -sa * (-j[0, 0] * sb + j[0, 1] * cb) + ca * (-j[1, 0] * sb + j[1, 1] * cb)
        lam = np.clip(m00, LO, HI)
        best = (np.sum(j * j) - 2 * (lam * m00 + m11) + lam * lam + 1).min()
        assert np.sum((j - p) ** 2) <= best + 1e-9
        assert np.sum((j - p) ** 2) >= best - 2e-4                # the grid's resolution


def test_a_spherical_cap_prints_along_its_isolines_with_the_geodesic_shrink():
    hf = shapes.dome(diameter_mm=100.0, height_mm=25.0)
    radius = shapes.dome_radius_mm(100.0, 25.0)
    mesh = build_grid_mesh(hf, 1.5)
    flat = flatten_free(mesh, 0.0, 0.34)
    assert flat.flipped == 0 and flat.invalid_area_fraction < 0.02
    c = mesh.vertices[mesh.faces].mean(axis=1)
    r = np.hypot(c[:, 0] - 50.0, c[:, 1] - 50.0)
    phi = np.arcsin(np.clip(r / radius, 0, 1))
    sel = flat.sigma > 0.05
    assert sel.sum() > 100
    # The isoline direction in the layout: across the radius from the layout's centre.
    xy = flat.xy[mesh.faces].mean(axis=1)
    centre = flat.xy[np.argmax(mesh.vertices[:, 2])]
    radial = (xy - centre) / np.linalg.norm(xy - centre, axis=1)[:, None]
    angle = np.degrees(np.arccos(np.clip(np.abs(np.sum(flat.direction * radial, axis=1)), 0, 1)))
    assert np.percentile(90.0 - angle[sel], 95) < 10.0
    expected = 1.0 - np.sin(phi) / phi
    assert np.median(np.abs(flat.sigma[sel] - expected[sel])) < 0.01


@pytest.mark.parametrize("name", ["hyperbolic_paraboloid", "monkey_saddle"])
def test_saddles_form_with_a_free_direction(name):
    from pipeline.input.validate import validate
    from pipeline.layout.isoline import flatten
    from pipeline.meshing.isoline import build_mesh
    hf = shapes.SADDLES[name]()
    free = flatten_free(build_grid_mesh(hf, 2.0), 0.0, 0.34)
    assert free.flipped == 0 and free.invalid_area_fraction < 0.02
    # The paper's method, meshed as the shipped profile meshes: its isolines would have
    # to stretch on more than a fifth of their edges.
    mp = load_profile("generic-0.5mm").mesh
    hf, _ = validate(hf, 2.0)
    iso = flatten(build_mesh(hf, isoline_step_mm=mp.isoline_step_mm,
                             gradient_spacing_mm=mp.gradient_spacing_mm, l_u_mm=mp.l_u_mm),
                  s_min=0.0, s_max=0.34, iterations=50)
    stretch = float(np.mean(iso.sigma < -1e-3))
    assert stretch > 0.20, stretch


@pytest.mark.slow
def test_no_height_field_breaks_the_free_method():
    """Seeded random terrains (noise, ridges, terraces, plateaus, cliffs; 60-200 mm):
    meshing and the free layout raise nothing but documented errors and never flip."""
    from pipeline.input.simplify import simplify
    from pipeline.input.validate import validate
    flips, planned = [], 0
    for seed in range(200):
        hf = random_terrain(seed)
        try:
            hf, _ = validate(hf, 5.0)
            hf, _ = simplify(hf, 2.0, 1.0)
            mesh = build_grid_mesh(hf, max(hf.pixel_mm * 2, 2.0))
            flat = flatten_free(mesh, 0.0, 0.34, iterations=60)
        except PipelineError:
            continue
        planned += 1
        if flat.flipped:
            flips.append((seed, flat.flipped))
    assert not flips
    assert planned >= 150, planned


def test_violation_names_stretch_and_overshrink():
    J = np.array([np.diag([1.2, 0.9]), np.diag([1.9, 1.0]), np.diag([1.2, 1.3]),
                  np.diag([1.2, 1.0])])
    stretch, over = violation(J, LO, HI)
    assert list(stretch) == [True, False, False, False]
    assert list(over) == [False, True, True, False]
