"""Small geometry helpers over numpy arrays."""

import numpy as np

from pipeline.geometry import polyline_length, polyline_lengths


def test_many_polylines_measure_as_each_alone():
    """The lengths of many pieces at once are each piece's own, with no step counted
    from one piece's last point to the next one's first, and 0 for a piece of one point
    or none, wherever it stands in the list."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        pieces = [rng.random((k, 2)) * 10 for k in rng.integers(0, 5, rng.integers(1, 7))]
        assert np.allclose(polyline_lengths(pieces), [polyline_length(p) for p in pieces])
    assert polyline_lengths([np.array([[0.0, 0.0], [3.0, 4.0]]), np.zeros((0, 2))]).tolist() \
        == [5.0, 0.0]
    assert len(polyline_lengths([])) == 0
