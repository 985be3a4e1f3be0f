"""The isoline method's sheet, settled as a thin shell, converges under refinement: its
mean displacement changes by less than 10 % when the mesh is refined twofold."""

import pytest

from pipeline.layout.isoline import flatten
from pipeline.meshing.isoline import build_mesh
from pipeline.simulation.shell import isoline_rest, simulate_shell

from meshes import LIMITS as LIM, refines_within, sheet_thickness


def isoline_sheet(hf, spacing_mm):
    """The isoline method's layout (isolines ``spacing_mm`` apart, printing edges at
    most that long) settled as a thin shell: SimResult."""
    mesh = build_mesh(hf, isoline_step_mm=spacing_mm, gradient_spacing_mm=2 * spacing_mm,
                      l_u_mm=spacing_mm)
    flat = flatten(mesh, s_min=LIM.s_min, s_max=LIM.s_max)
    rest, sigma, _ = isoline_rest(mesh, flat.xy, LIM.s_min, LIM.s_max)
    return simulate_shell(mesh.vertices, mesh.faces, flat.xy, rest, sheet_thickness(sigma))


# The isoline method folds the monkey saddle (its layout flips triangles: the shape
# needs stretch along the isolines), so there is no sheet to converge to.
@pytest.mark.slow
@pytest.mark.parametrize("shape", ["dome", "starfish"])
def test_isoline_sheet_converges_under_refinement(shape):
    refines_within(isoline_sheet, shape)
