"""What would form an input as given: the size at which its curvature is within the
stack's reach, and the thinner stack that would reach it."""

import pytest

from pipeline.layout.keep import keep, sentence
from pipeline.layout.reach import WITHIN


def test_curvature_beyond_reach_forms_at_a_larger_size_or_on_fewer_layers():
    k = keep(2 * WITHIN, True, 60.0, 6)
    # Curvature falls as one over the size: twice the reach needs twice the size.
    assert k["size_mm_as_given"] == pytest.approx(120.0) and k["size_factor"] == 2.0
    # The limit grows as one over the stack: half the layers curl twice as tight.
    assert k["layers_as_given"] == 3
    text = sentence(k)
    assert "`size_mm: 120` (now 60 mm)" in text and "3 layers instead of 6" in text


def test_slopes_too_steep_form_at_no_size():
    k = keep(0.1, False, 60.0, 6)
    assert k["size_mm_as_given"] is None
    assert "only a lower or smoother relief" in sentence(k)


def test_no_stack_reaches_a_curvature_far_beyond():
    k = keep(10 * 6 * WITHIN, True, 50.0, 6)      # one layer still ten times short
    assert k["layers_as_given"] is None
    assert "one layer would still need 10.0 times its reach" in sentence(k)


def test_an_input_that_forms_says_nothing():
    k = keep(0.5 * WITHIN, True, 80.0, 6)
    assert k["size_mm_as_given"] == 80.0 and k["layers_as_given"] == 6
    assert sentence(k) == ""
