"""Projective-dynamics machinery (pipeline.mechanics.constraints, pipeline.mechanics.pd): projections,
hinge rows, energy descent."""

import numpy as np
import pytest

from pipeline.geometry import edge_lengths
from pipeline.mechanics.constraints import (corner_coefficients, face_geometry, hinge_weights,
                                  project_corners, project_edges, topology)
from pipeline.mechanics.pd import EdgeTargets, PDSystem, minimize, minimize_lbfgs

from meshes import reference_mesh, spherical_cap

RNG = np.random.default_rng(12345)


@pytest.fixture(autouse=True)
def _fresh_rng():
    """Each test draws the same numbers whichever tests ran before it in its worker."""
    global RNG
    RNG = np.random.default_rng(12345)


def _angle(U0, U1, planar):
    dot = np.einsum("ij,ij->j", U0, U1)
    if planar:
        return np.arctan2(U0[0] * U1[1] - U0[1] * U1[0], dot)
    return np.arctan2(np.linalg.norm(np.cross(U0.T, U1.T), axis=1), dot)


def _random_corners(k, d, spread=0.6):
    """Corners whose angle is within ~spread rad of a random rest angle."""
    theta0 = RNG.uniform(0.3, 2.6, k)
    theta = np.clip(theta0 + RNG.uniform(-spread, spread, k), 0.05, 3.0)
    L0, L1 = RNG.uniform(0.3, 3.0, k), RNG.uniform(0.3, 3.0, k)
    U0 = np.zeros((d, k))
    U1 = np.zeros((d, k))
    U0[0] = L0
    U1[0], U1[1] = L1 * np.cos(theta), L1 * np.sin(theta)
    if d == 3:  # rotate each corner's plane randomly
        for i in range(k):
            q, _ = np.linalg.qr(RNG.normal(size=(3, 3)))
            U0[:, i], U1[:, i] = q @ U0[:, i], q @ U1[:, i]
    return U0, U1, theta0


# -- edge strain ------------------------------------------------------------

def test_edge_projection_is_idempotent_and_lands_in_range():
    Y = RNG.normal(size=(3, 500))
    lo, hi = RNG.uniform(0.2, 1.0, 500), RNG.uniform(1.0, 2.0, 500)
    P = project_edges(Y, lo, hi)
    length = np.linalg.norm(P, axis=0)
    assert np.all(length >= lo - 1e-12) and np.all(length <= hi + 1e-12)
    np.testing.assert_allclose(project_edges(P, lo, hi), P, atol=1e-14)
    inside = (np.linalg.norm(Y, axis=0) >= lo) & (np.linalg.norm(Y, axis=0) <= hi)
    np.testing.assert_allclose(P[:, inside], Y[:, inside])  # feasible vectors stay


def test_edge_projection_is_the_nearest_feasible_vector():
    Y = RNG.normal(size=(3, 200))
    lo, hi = np.full(200, 0.8), np.full(200, 1.2)
    d = np.linalg.norm(Y - project_edges(Y, lo, hi), axis=0)
    for _ in range(50):
        q = RNG.normal(size=(3, 200))
        q *= RNG.uniform(0.8, 1.2, 200) / np.linalg.norm(q, axis=0)
        assert np.all(d <= np.linalg.norm(Y - q, axis=0) + 1e-12)


# -- shear (corner angle) -----------------------------------------------------

@pytest.mark.parametrize("planar", [False, True])
def test_corner_projection_hits_rest_angle_and_is_idempotent(planar):
    U0, U1, theta0 = _random_corners(300, 2 if planar else 3)
    P0, P1 = project_corners(U0, U1, np.cos(theta0), np.sin(theta0), planar)
    np.testing.assert_allclose(_angle(P0, P1, planar), theta0, atol=1e-9)
    Q0, Q1 = project_corners(P0, P1, np.cos(theta0), np.sin(theta0), planar)
    np.testing.assert_allclose(Q0, P0, atol=1e-12)
    np.testing.assert_allclose(Q1, P1, atol=1e-12)
    # equal lengths rotate symmetrically and keep their lengths to second order
    A0 = U0 / np.linalg.norm(U0, axis=0)
    A1 = U1 / np.linalg.norm(U1, axis=0)
    B0, B1 = project_corners(A0, A1, np.cos(theta0), np.sin(theta0), planar)
    turn0 = np.arccos(np.clip(np.einsum("ij,ij->j", A0, B0) / np.linalg.norm(B0, axis=0), -1, 1))
    turn1 = np.arccos(np.clip(np.einsum("ij,ij->j", A1, B1) / np.linalg.norm(B1, axis=0), -1, 1))
    np.testing.assert_allclose(turn0, turn1, atol=1e-9)


@pytest.mark.parametrize("planar", [False, True])
def test_corner_projection_is_the_nearest_pair_with_that_angle(planar):
    """Brute force over the split of the rotation: nothing feasible is closer."""
    U0, U1, theta0 = _random_corners(60, 2 if planar else 3)
    P0, P1, r2 = project_corners(U0, U1, np.cos(theta0), np.sin(theta0), planar,
                                 return_residual=True)
    dist2 = np.sum((U0 - P0) ** 2, axis=0) + np.sum((U1 - P1) ** 2, axis=0)
    np.testing.assert_allclose(r2, dist2, rtol=1e-9, atol=1e-12)
    theta = _angle(U0, U1, planar)
    delta = theta0 - theta
    L0, L1 = np.sum(U0 ** 2, axis=0), np.sum(U1 ** 2, axis=0)
    a0 = np.linspace(-np.pi / 2, np.pi / 2, 20001)[:, None]
    a1 = delta[None, :] - a0
    # best feasible pair for each split: each vector dropped onto its rotated line
    cost = L0 * np.sin(a0) ** 2 * (np.cos(a0) > 0) + L0 * (np.cos(a0) <= 0) \
        + L1 * np.sin(a1) ** 2 * (np.cos(a1) > 0) + L1 * (np.cos(a1) <= 0)
    assert np.all(dist2 <= cost.min(axis=0) + 1e-9)


def test_corner_kernel_matches_vector_projection():
    U0, U1, theta0 = _random_corners(100, 3)
    P0, P1 = project_corners(U0, U1, np.cos(theta0), np.sin(theta0))
    L0, L1 = np.sum(U0 ** 2, 0), np.sum(U1 ** 2, 0)
    a00, a01, a10, a11, _ = corner_coefficients(L0, L1, np.sum(U0 * U1, 0), None,
                                                np.cos(theta0), np.sin(theta0))
    np.testing.assert_allclose(a00 * U0 + a01 * U1, P0, atol=1e-12)
    np.testing.assert_allclose(a10 * U0 + a11 * U1, P1, atol=1e-12)


def test_planar_corner_projection_unflips_a_flipped_corner():
    U0 = np.array([[1.0], [0.0]])
    U1 = np.array([[np.cos(-0.4)], [np.sin(-0.4)]])  # clockwise: flipped
    P0, P1 = project_corners(U0, U1, np.cos([0.5]), np.sin([0.5]), planar=True)
    assert P0[0, 0] * P1[1, 0] - P0[1, 0] * P1[0, 0] > 0


# -- bending ------------------------------------------------------------------

def test_hinge_rows_vanish_on_flat_rest_state_and_on_translations():
    mesh, _ = spherical_cap(l_u=3.0, ring_arc_mm=6.0)
    top = topology(mesh.faces)
    flat = mesh.vertices.copy()
    flat[:, 2] = 0.0
    K = hinge_weights(top, edge_lengths(flat, top.edges))
    np.testing.assert_allclose(K.sum(axis=1), 0.0, atol=1e-9)
    bend = np.einsum("hk,hkd->hd", K, flat[top.hinges])
    assert np.abs(bend).max() < 1e-9
    # on the curved target the same rows measure curvature
    Kc = hinge_weights(top, edge_lengths(mesh.vertices, top.edges))
    assert np.abs(np.einsum("hk,hkd->hd", Kc, mesh.vertices[top.hinges])).max() > 1e-3


def test_hinges_beside_a_degenerate_triangle_get_no_bending_row():
    """A strip of hinges: the two beside the needle (a 0.3 degree corner) have
    zero rows, the others keep their cotangent rows."""
    # four triangles along a strip; the middle one is a needle
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2], [60, 0.5, 0.0],
                    [1, 2, 0.1]], float)
    faces = np.array([[0, 1, 2], [1, 3, 2], [1, 4, 3], [2, 3, 5]])
    top = topology(faces)
    L = edge_lengths(pts, top.edges)
    _, _, angle = face_geometry(top, L)
    needle = np.degrees(angle.min(axis=1)) < 1.0
    assert needle.tolist() == [False, False, True, False]
    K = hinge_weights(top, L)
    beside = needle[top.hinge_faces].any(axis=1)
    assert beside.any() and (~beside).any()
    assert np.all(K[beside] == 0.0)
    assert np.all(np.abs(K[~beside]).sum(axis=1) > 0.1)


def test_face_geometry_angles_sum_to_pi():
    mesh = reference_mesh("dome")
    top = topology(mesh.faces)
    area, cot, angle = face_geometry(top, edge_lengths(mesh.vertices, top.edges))
    np.testing.assert_allclose(angle.sum(axis=1), np.pi, atol=1e-9)
    np.testing.assert_allclose(1.0 / np.tan(angle), cot, rtol=1e-6, atol=1e-9)


# -- the assembled system -------------------------------------------------------

def _system(mesh, seed=0):
    top = topology(mesh.faces)
    l0 = edge_lengths(mesh.vertices, top.edges)
    rng = np.random.default_rng(seed)
    edge = EdgeTargets(l0, l0 * rng.uniform(1.0, 1.5, len(l0)), rng.uniform(0.5, 1.0, len(l0)), l0)
    return PDSystem(top, edge, l0, w_bending=0.05, w_shear=0.3)


@pytest.mark.parametrize("planar", [False, True])
def test_fused_local_step_equals_explicit_rows(planar):
    """The half-edge local step is A^T W P with the stacked rows A."""
    mesh = reference_mesh("saddle")
    S = _system(mesh)
    X = mesh.vertices.T + RNG.normal(0, 0.3, mesh.vertices.T.shape)
    X = X[:2].copy() if planar else X
    Q, E = S.project(X, planar)
    Y = np.stack([S.A @ x for x in X])
    e, c = S.n_edges, S.n_corners
    P = np.concatenate([project_edges(Y[:, :e], S.edge_lo, S.edge_hi),
                        *project_corners(Y[:, e:e + c], Y[:, e + c:], S.cos0, S.sin0, planar)], 1)
    w = np.concatenate([S.edge_w, np.full(2 * c, S.w_shear)])
    rhs = np.stack([S.A.T @ (w * p) for p in P])
    Qs, Pe = Q
    fused = np.stack([S.DT @ q + S.AeT @ p for q, p in zip(Qs, Pe)])
    np.testing.assert_allclose(fused, rhs, atol=1e-10)
    assert E == pytest.approx(sum(S.energy_terms(X, planar).values()), rel=1e-9)


@pytest.mark.parametrize("planar", [False, True])
def test_energy_never_increases_over_local_global_iterations(planar):
    mesh = reference_mesh("elongated_peak")
    S = _system(mesh, seed=3)
    for trial in range(3):
        X = mesh.vertices.T + RNG.normal(0, 0.8, mesh.vertices.T.shape)
        X = X[:2].copy() if planar else X
        energies = []
        for _ in range(15):
            X, E = S.step(X, planar)
            energies.append(E)
        energies.append(S.energy(X, planar))
        assert np.all(np.diff(energies) <= 1e-9 * energies[0]), energies


def test_anderson_acceleration_keeps_energy_monotone_and_helps():
    mesh = reference_mesh("saddle")
    S = _system(mesh, seed=5)
    X0 = mesh.vertices.T + RNG.normal(0, 1.0, mesh.vertices.T.shape)
    _, e_aa, _, _ = minimize(S, X0, 40, 0.0, anderson=5)
    _, e_pd, _, _ = minimize(S, X0, 40, 0.0, anderson=0)
    assert np.all(np.diff(e_aa) <= 1e-9 * e_aa[0])
    assert e_aa[-1] < e_pd[-1]


def test_gradient_matches_finite_differences_of_the_energy():
    """L-BFGS steers by ``gradient``: it must be the energy's derivative."""
    mesh = reference_mesh("saddle")
    S = _system(mesh, seed=9)
    X = mesh.vertices.T + RNG.normal(0, 0.5, mesh.vertices.T.shape)
    Q, E = S.project(X)
    G = S.gradient(Q, X)
    for _ in range(3):
        V = RNG.normal(size=X.shape)
        h = 1e-6
        fd = (S.energy(X + h * V) - S.energy(X - h * V)) / (2 * h)
        assert fd == pytest.approx(float(np.vdot(G, V)), rel=1e-5)


def test_lbfgs_keeps_energy_monotone():
    """The forward simulation's solver never raises the energy (its line
    search backtracks instead); how far it gets on soft modes is tested in
    ``test_simulate*.py``."""
    mesh = reference_mesh("saddle")
    S = _system(mesh, seed=5)
    X0 = mesh.vertices.T + RNG.normal(0, 1.0, mesh.vertices.T.shape)
    X, e_lb, it, _ = minimize_lbfgs(S, X0, 40, rest_tol=0.0)
    assert it == 40
    e_lb = e_lb + [S.energy(X)]
    assert np.all(np.diff(e_lb) <= 1e-12 * e_lb[0])
    assert e_lb[-1] < 0.01 * e_lb[0]


def test_lbfgs_stops_at_rest_over_a_window():
    """At rest means moved less than ``rest_tol`` (RMS) over the last ten
    iterations, not one small step."""
    mesh = reference_mesh("dome")
    S = _system(mesh, seed=2)
    X0 = mesh.vertices.T + RNG.normal(0, 0.3, mesh.vertices.T.shape)
    X, energies, it, converged = minimize_lbfgs(S, X0, 2000, rest_tol=1e-4)
    assert converged and 10 <= it < 2000
    X2, _, it2, _ = minimize_lbfgs(S, X, 10, rest_tol=0.0)
    d = X2 - X
    assert np.sqrt(np.einsum("ij,ij->", d, d) / X.shape[1]) < 1e-3


def test_global_step_keeps_a_satisfied_configuration():
    """At the rest shape every projection is the identity: x is a fixed point."""
    mesh = reference_mesh("dome")
    top = topology(mesh.faces)
    l0 = edge_lengths(mesh.vertices, top.edges)
    S = PDSystem(top, EdgeTargets(l0, l0, np.ones(len(l0)), l0), l0, w_bending=0.0)
    X, E = S.step(mesh.vertices.T.copy())
    assert E < 1e-18
    np.testing.assert_allclose(X, mesh.vertices.T, atol=1e-8)
