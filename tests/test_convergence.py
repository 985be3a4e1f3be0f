"""The thin-shell simulation answers for the sheet, not for the mesh: its mean
displacement changes by less than 10 % when the mesh is refined twofold."""

import numpy as np
import pytest

from pipeline.input import shapes
from pipeline.layout import curvature
from pipeline.layout.free import flatten_free
from pipeline.layout.isoline import flatten
from pipeline.meshing.grid import build_grid_mesh
from pipeline.meshing.isoline import build_mesh
from pipeline.profiles.profile import load_profile
from pipeline.simulation.shell import (directional_rest, isoline_rest, simulate_shell,
                                       thickness_for)

PROFILE = load_profile("generic-0.5mm")
LIM = PROFILE.shrink_limits
SIZE_MM = 60.0
# A 60 mm model meshed every 0.9 mm has the plan's relative resolution of a 100 mm
# model every 1.5 mm: coarser than the shipped profiles, so a pass here is on the safe side.
SPACING_MM = 0.9

SHAPES = {
    "dome": lambda: shapes.dome(SIZE_MM, SIZE_MM * 25 / 120, pixel_mm=0.2),
    "monkey_saddle": lambda: shapes.monkey_saddle(SIZE_MM, SIZE_MM * 22 / 136, pixel_mm=0.2),
    "starfish": lambda: shapes.starfish(SIZE_MM, SIZE_MM * 33.4 / 175, pixel_mm=0.2),
}


def _thickness(sigma):
    return thickness_for(sigma, PROFILE.shrink_curve, PROFILE.layers,
                         PROFILE.thickness_mm.min, PROFILE.thickness_mm.max)


def free_sheet(hf, spacing_mm):
    """The free method's sheet as the plan simulates it: starts flat, curvature
    programmed through the layers. Returns the mean displacement (mm)."""
    mesh = build_grid_mesh(hf, spacing_mm)
    flat = flatten_free(mesh, LIM.s_min, LIM.s_max, iterations=200)
    sigma = np.clip(flat.sigma, LIM.s_min, LIM.s_max)
    thick = _thickness(sigma)
    program = curvature.program(curvature.along_print_direction(hf, mesh, flat), mesh.faces,
                                flat.xy, flat.direction, sigma, thick, LIM.s_min, LIM.s_max)
    sim = simulate_shell(mesh.vertices, mesh.faces, flat.xy,
                         directional_rest(flat.xy, mesh.faces, flat.direction, sigma), thick,
                         theta_rest=program.theta_rest, pop=0.0)
    return sim.mean_displacement_mm


def isoline_sheet(hf, spacing_mm):
    """The isoline method's layout (isolines ``spacing_mm`` apart, printing edges at
    most that long) settled as a thin shell. Returns the mean displacement (mm)."""
    mesh = build_mesh(hf, isoline_step_mm=spacing_mm, gradient_spacing_mm=2 * spacing_mm,
                      l_u_mm=spacing_mm)
    flat = flatten(mesh, s_min=LIM.s_min, s_max=LIM.s_max)
    rest, sigma, _ = isoline_rest(mesh, flat.xy, LIM.s_min, LIM.s_max)
    sim = simulate_shell(mesh.vertices, mesh.faces, flat.xy, rest, _thickness(sigma))
    return sim.mean_displacement_mm


# The isoline method folds the monkey saddle (its layout flips triangles: the shape
# needs stretch along the isolines), so there is no sheet to converge to.
@pytest.mark.slow
@pytest.mark.parametrize("method,shape", [
    ("free", "dome"), ("free", "monkey_saddle"), ("free", "starfish"),
    ("isoline", "dome"), ("isoline", "starfish")])
def test_simulated_displacement_converges_under_refinement(method, shape):
    hf = SHAPES[shape]()
    sheet = free_sheet if method == "free" else isoline_sheet
    coarse, fine = sheet(hf, SPACING_MM), sheet(hf, SPACING_MM / 2)
    assert fine > 0
    assert abs(coarse - fine) < 0.10 * fine, (coarse, fine)
