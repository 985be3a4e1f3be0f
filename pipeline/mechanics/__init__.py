"""Sheet mechanics shared by the layout methods and the simulation: projective dynamics
(``pd``: local/global solves, L-BFGS) over the sheet constraints (``constraints``)."""
