"""Tool paths on the flat layout: one module per method (``isoline``: level sets of one fitted
field, as the paper), and the figures of a path plan (``stats``)."""
