"""The thin-shell simulation answers for the sheet, not for the mesh: its mean
displacement changes by less than 10 % when the mesh is refined twofold (the free
method's sheets here, the isoline method's in ``test_convergence_isoline.py``)."""

import pytest

from meshes import free_sheet, refines_within


@pytest.mark.slow
@pytest.mark.parametrize("shape", ["dome", "monkey_saddle", "starfish"])
def test_free_sheet_converges_under_refinement(shape):
    refines_within(free_sheet, shape)
