"""The free layout's solver: the local step without trigonometry gives the projection's
matrices, and a target laid out again reuses its factored global system."""

import numpy as np

from pipeline.input import shapes
from pipeline.layout import free
from pipeline.layout.free import flatten_free, global_system, project, projected
from pipeline.meshing.grid import build_grid_mesh

LO, HI = 1.0, 1.0 / (1.0 - 0.34)


def test_the_local_step_is_the_projection():
    rng = np.random.default_rng(3)
    J = rng.normal(scale=0.6, size=(2000, 2, 2)) + np.eye(2)
    # The parts of norm 0: a similarity, a reflection, nothing, a rotation by a half turn.
    J[:4] = [[[1.2, 0], [0, 1.2]], [[0.5, 0.3], [0.3, -0.5]], [[0, 0], [0, 0]],
             [[-1, 0], [0, -1]]]
    assert np.allclose(projected(J, LO, HI), project(J, LO, HI)[0], atol=1e-12)


def test_the_same_target_is_factored_once():
    free._systems.clear()
    mesh = build_grid_mesh(shapes.dome(diameter_mm=40.0, height_mm=8.0), 2.0)
    first = global_system(mesh.vertices, mesh.faces)
    # Equal contents, not the same array: the relaid layouts pass copies.
    assert global_system(mesh.vertices.copy(), mesh.faces.copy()) is first
    higher = mesh.vertices * [1.0, 1.0, 1.5]
    assert global_system(higher, mesh.faces) is not first
    flat = flatten_free(mesh, 0.0, 0.34)
    free._systems.clear()
    again = flatten_free(mesh, 0.0, 0.34)
    assert np.array_equal(flat.xy, again.xy) and flat.iterations == again.iterations


def test_the_solve_stops_where_its_residual_stalls(monkeypatch):
    """A dome's layout stops well before its cap once the residual barely falls, and
    lies within a hundredth of a millimetre of the layout 200 plain steps give (mixed
    steps run to a cap creep further along the same soft modes)."""
    mesh = build_grid_mesh(shapes.dome(diameter_mm=60.0, height_mm=10.0), 1.0)
    stalled = flatten_free(mesh, 0.0, 0.34, iterations=200)
    monkeypatch.setattr(free, "STALL", -1.0)        # falls never stall: run to the cap
    monkeypatch.setattr(free, "ANDERSON", 0)
    capped = flatten_free(mesh, 0.0, 0.34, iterations=200)
    assert capped.iterations == 200 and stalled.converged and stalled.iterations < 100
    assert np.abs(stalled.xy - capped.xy).max() < 0.01
    assert stalled.residual < 1.05 * capped.residual


def test_a_plan_keeps_no_layout_systems_once_its_sheet_is_settled(tmp_path):
    """The factored systems serve the fit, the layout and its relaid passes; once the
    sheet is settled they would only sit under the tool paths' peak (tens of MB)."""
    from pipeline.plan import plan_file
    from pipeline.profiles.profile import load_profile
    hf = shapes.dome(diameter_mm=30.0, height_mm=5.0)
    np.save(tmp_path / "dome.npy", hf.z.astype(np.float32))
    (tmp_path / "dome.yaml").write_text("pixel_mm: %r\n" % hf.pixel_mm)
    plan = plan_file(tmp_path / "dome.npy", load_profile("generic-0.5mm"), method="free")
    assert plan.report["flatten"]["method"] == "free" and not free._systems


def test_mixed_steps_rest_closer_in_a_quarter_of_the_solves(monkeypatch):
    """A saddle's layout creeps along soft modes under plain local/global steps; mixed by
    Anderson acceleration, 50 solves rest closer to the admissible maps than 200 plain
    ones (the residual: 5.2e-4 against 9.2e-4)."""
    mesh = build_grid_mesh(shapes.SADDLES["hyperbolic_paraboloid"](), 2.0)
    monkeypatch.setattr(free, "STALL", -1.0)
    mixed = flatten_free(mesh, 0.0, 0.34, iterations=50)
    monkeypatch.setattr(free, "ANDERSON", 0)
    plain = flatten_free(mesh, 0.0, 0.34, iterations=200)
    assert mixed.iterations == 50 and plain.iterations == 200
    assert mixed.residual < 0.8 * plain.residual
    assert mixed.flipped == 0 and mixed.invalid_area_fraction <= plain.invalid_area_fraction
