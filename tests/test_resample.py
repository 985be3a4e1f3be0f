"""An isoline layout checked as a thin shell on a plain grid: the sheet resampled
shrinks along the isolines as the layout does, settles where the isoline mesh's own
shell does, and a plan that asks for it reports the grid's sheet."""

import dataclasses

import numpy as np
import pytest

from hostd import planner
from pipeline.geometry import edge_lengths, hat_gradients
from pipeline.input import shapes
from pipeline.layout.isoline import flatten
from pipeline.profiles.profile import load_profile
from pipeline.simulation.resample import onto_grid
from pipeline.simulation.shell import directional_rest, isoline_rest, simulate_shell

from meshes import isoline_mesh, longest_diameter, sheet_thickness


def _dome():
    hf = shapes.dome(diameter_mm=60.0, height_mm=12.5, pixel_mm=0.25)
    mesh = isoline_mesh(hf, spacing_mm=1.0, l_u=0.5)
    return hf, mesh, flatten(mesh)


def test_the_grid_sheet_shrinks_along_the_isolines_as_the_layout_does():
    hf, mesh, flat = _dome()
    sheet = onto_grid(hf, mesh, flat.xy, 1.0)
    pe = np.asarray(mesh.printing_edges)
    s_edge = 1.0 - edge_lengths(mesh.vertices, pe) / edge_lengths(flat.xy, pe)
    centre = np.asarray(mesh.vertices)[np.argmax(mesh.vertices[:, 2]), :2]
    r_edge = np.linalg.norm(mesh.vertices[pe].mean(axis=1)[:, :2] - centre, axis=1)
    r_grid = np.linalg.norm(sheet.vertices[sheet.faces].mean(axis=1)[:, :2] - centre, axis=1)
    # Ring by ring, the shrink of the layout's map along d is its printing edges' shrink.
    for lo in (10.0, 15.0, 20.0, 25.0):
        ring = np.median(s_edge[(r_edge >= lo) & (r_edge < lo + 5)])
        assert np.median(sheet.sigma[(r_grid >= lo) & (r_grid < lo + 5)]) == pytest.approx(
            ring, rel=0.1, abs=0.002)
    # ... and d runs along the isolines: across the height's gradient.
    g = np.einsum("fk,fkc->fc", sheet.vertices[sheet.faces][:, :, 2],
                  hat_gradients(sheet.xy, sheet.faces)[0])
    assert np.median(np.abs(np.einsum("fc,fc->f", g, sheet.direction))
                     / np.linalg.norm(g, axis=1)) < 1e-6


def test_the_grid_sheet_settles_where_the_isoline_mesh_does():
    hf, mesh, flat = _dome()
    ld = longest_diameter(mesh)
    rest, s_face, _ = isoline_rest(mesh, flat.xy)
    own = simulate_shell(mesh.vertices, mesh.faces, flat.xy, rest, sheet_thickness(s_face))
    sheet = onto_grid(hf, mesh, flat.xy, 1.0)
    grid = simulate_shell(sheet.vertices, sheet.faces, sheet.xy,
                          directional_rest(sheet.xy, sheet.faces, sheet.direction, sheet.sigma),
                          sheet_thickness(sheet.sigma))
    assert own.mean_displacement_mm < 0.02 * ld
    assert abs(grid.mean_displacement_mm - own.mean_displacement_mm) < 0.005 * ld
    # Shrunk across the isolines instead, the grid sheet does not form the dome.
    across = np.stack([-sheet.direction[:, 1], sheet.direction[:, 0]], axis=1)
    wrong = simulate_shell(sheet.vertices, sheet.faces, sheet.xy,
                           directional_rest(sheet.xy, sheet.faces, across, sheet.sigma),
                           sheet_thickness(sheet.sigma))
    assert wrong.mean_displacement_mm > 3 * own.mean_displacement_mm


def test_a_plan_that_asks_for_the_shell_reports_the_grid_sheet(tmp_path):
    hf = shapes.dome(diameter_mm=50.0, height_mm=10.0)
    np.save(tmp_path / "dome.npy", hf.z)
    (tmp_path / "dome.yaml").write_text("pixel_mm: %r\n" % hf.pixel_mm)
    prof = load_profile("generic-0.5mm")
    shell = dataclasses.replace(prof, flatten=dataclasses.replace(prof.flatten, method="isoline",
                                                                  simulation="shell"))
    plan = planner.run(tmp_path / "dome.npy", shell, tmp_path / "out")
    sim = plan.report["simulation"]
    assert sim["coarse_iterations"] == 0 and sim["converged"]
    assert sim["sheet_vertices"] == len(plan.sim.vertices) != len(plan.mesh.vertices)
    assert sim["mean_displacement_fraction"] < 0.02
    ply = (tmp_path / "out" / "dome.simulated.ply").read_bytes()
    assert b"element face %d" % len(plan.sim.faces) in ply
    paper = planner.run(tmp_path / "dome.npy", prof, tmp_path / "paper")
    assert paper.report["simulation"]["sheet_vertices"] == len(paper.mesh.vertices)
