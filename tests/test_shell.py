"""The thin-shell model: exact gradients, projections, rest states and programmed curvature."""

import numpy as np
import pytest

from pipeline.layout.curvature import isoline_directions
from pipeline.layout.isoline import flatten
from pipeline.mechanics.constraints import topology
from pipeline.mechanics.pd import minimize_lbfgs
from pipeline.mechanics.shell import (ShellSystem, dihedral, face_lengths, min_angle_deg,
                                      nearest_orthonormal)
from pipeline.simulation.forward import simulate
from pipeline.simulation.shell import directional_rest, isoline_rest, simulate_shell

from meshes import flat_sheet, longest_diameter, reference_mesh, roll_curvature


def _numeric_gradient(f, X, h=1e-6):
    g = np.zeros_like(X)
    for idx in np.ndindex(*X.shape):
        d = np.zeros_like(X)
        d[idx] = h
        g[idx] = (f(X + d) - f(X - d)) / (2 * h)
    return g


def test_dihedral_gradient_matches_finite_differences():
    rng = np.random.default_rng(3)
    H = np.array([[0, 1, 2, 3]])
    for _ in range(5):
        V = rng.normal(size=(4, 3))
        _, g = dihedral(V, H, with_gradient=True)
        num = _numeric_gradient(lambda W: dihedral(W, H)[0], V)
        assert np.allclose(g[0], num, atol=1e-6 * np.abs(num).max())


def test_dihedral_sign_tells_a_dome_from_a_bowl():
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0.0]])
    H = np.array([[0, 1, 2, 3]])
    assert dihedral(V, H)[0] == pytest.approx(0.0)
    bowl = V.copy()
    bowl[2:, 2] = 0.3
    dome = V.copy()
    dome[2:, 2] = -0.3
    assert dihedral(bowl, H)[0] < 0 < dihedral(dome, H)[0]


def test_nearest_orthonormal_is_the_polar_factor():
    rng = np.random.default_rng(4)
    F = rng.normal(size=(50, 3, 2))
    R0, R1 = nearest_orthonormal([F[:, :, 0].T, F[:, :, 1].T])
    R = np.stack([R0.T, R1.T], axis=2)
    U, _, Vt = np.linalg.svd(F, full_matrices=False)
    assert np.allclose(R, U @ Vt, atol=1e-9)


def test_energy_gradient_is_exact():
    V, faces = flat_sheet(jitter=0.4)
    rng = np.random.default_rng(5)
    rest = face_lengths(V, faces) * rng.uniform(0.7, 1.0, size=(len(faces), 1))
    theta = rng.normal(scale=0.1, size=len(topology(faces).hinges))
    S = ShellSystem(faces, len(V), rest, rng.uniform(0.5, 2.0, len(faces)), theta_rest=theta)
    X = (V + rng.normal(scale=0.5, size=V.shape)).T.copy()
    g, _ = S.project(X)
    sub = np.s_[:, ::9]
    num = np.zeros_like(X)
    for idx in np.ndindex(*X[sub].shape):
        i, j = idx[0], idx[1] * 9
        d = np.zeros_like(X)
        d[i, j] = 1e-6
        num[i, j] = (S.project(X + d)[1] - S.project(X - d)[1]) / 2e-6
    assert np.allclose(g[sub], num[sub], atol=1e-5 * np.abs(g).max())


def test_a_sheet_at_its_rest_shape_has_no_energy_and_no_force():
    V, faces = flat_sheet(jitter=0.4)
    S = ShellSystem(faces, len(V), face_lengths(V, faces), 1.5)
    g, E = S.project(V.T.copy())
    assert E == pytest.approx(0.0, abs=1e-18)
    assert np.abs(g).max() < 1e-9


def test_bending_grows_with_the_cube_of_thickness_and_stretch_with_thickness():
    V, faces = flat_sheet()
    bent = V.copy()
    bent[:, 2] = 0.02 * (bent[:, 0] - 12.0) ** 2      # a developable bend: no stretch to first order
    stretched = V * np.array([1.05, 1.0, 1.0])        # 5 % in-plane stretch, no bend
    terms = {}
    for h in (1.0, 2.0):
        S = ShellSystem(faces, len(V), face_lengths(V, faces), h)
        terms[h] = (S.energy_terms(bent.T.copy())["bending"],
                    S.energy_terms(stretched.T.copy())["membrane"])
    assert terms[2.0][0] / terms[1.0][0] == pytest.approx(8.0, rel=1e-9)
    assert terms[2.0][1] / terms[1.0][1] == pytest.approx(2.0, rel=1e-9)


def test_slivers_carry_no_bending():
    V, faces = flat_sheet()
    rest = face_lengths(V, faces)
    sliver = np.array([[1.0, 1.0, 1.9999]])           # corners of 0.6 degrees
    assert min_angle_deg(sliver)[0] < 1.0 < min_angle_deg(rest).min()
    rest[0] = sliver[0] * rest[0].max()
    S = ShellSystem(faces, len(V), rest, 1.5)
    hf = S.top.hinge_faces
    touches = (hf == 0).any(axis=1)
    assert touches.any() and np.all(S.k_hinge[touches] == 0) and np.all(S.k_hinge[~touches] > 0)


@pytest.mark.parametrize("kappa", [0.0, 1.0 / 30.0])
def test_a_strip_settles_to_its_programmed_curvature(kappa):
    """A strip whose hinges rest at the dihedral angles of a cylinder of curvature kappa
    rolls up to that cylinder from flat; with no programmed curvature it stays flat."""
    V, faces = flat_sheet(nx=25, ny=5, size=(40.0, 6.0), jitter=0.2, seed=1)
    hinges = topology(faces).hinges
    if kappa:
        phi = V[:, 0] * kappa
        rolled = np.c_[np.sin(phi) / kappa, V[:, 1], (1 - np.cos(phi)) / kappa]
    else:
        rolled = V.copy()
    S = ShellSystem(faces, len(V), face_lengths(V, faces), 1.0,
                    theta_rest=dihedral(rolled, hinges))
    X = V.T.copy()
    X[2] += 1e-3 * np.sin(V[:, 0])                    # a nudge off the flat saddle point
    X, _, _, converged = minimize_lbfgs(S, X, 2000, 1e-7)
    P = X.T
    assert converged
    fitted = roll_curvature(P)
    if kappa:
        assert fitted == pytest.approx(kappa, rel=0.05)
    else:
        assert np.ptp(P[:, 2]) < 1e-3


def test_free_simulation_along_the_isolines_matches_the_isoline_simulation():
    """The free method's sheet (each triangle shrunk by its sigma along ``d``, thin
    shell) with ``d`` set to the isoline direction settles where the isoline method's
    own simulation of the same layout does; turned across the isolines it does not."""
    mesh = reference_mesh("dome")
    flat = flatten(mesh)
    ld = longest_diameter(mesh)
    isoline = simulate(mesh, flat)
    _, sigma, _ = isoline_rest(mesh, flat.xy)
    d = isoline_directions(flat.xy, mesh.faces, mesh.vertex_level)
    thick = np.full(len(mesh.faces), 1.5)

    def free(direction):
        rest = directional_rest(flat.xy, mesh.faces, direction, sigma)
        return simulate_shell(mesh.vertices, mesh.faces, flat.xy, rest, thick)

    along, across = free(d), free(np.stack([-d[:, 1], d[:, 0]], axis=1))
    apart = np.linalg.norm(along.vertices - isoline.vertices, axis=1).mean() / ld
    assert apart < 0.005, apart
    assert abs(along.mean_displacement_mm - isoline.mean_displacement_mm) < 0.005 * ld
    assert np.linalg.norm(across.vertices - isoline.vertices, axis=1).mean() / ld > 10 * apart
