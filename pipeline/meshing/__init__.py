"""Meshing: the target surface as a triangle mesh (the isoline / gradient-line graph of the paper
in ``isoline``, with its contours, gradient lines and cell triangulation)."""
