"""Layout: the flat sheet to print and each region's shrink. One module per method
(``isoline``: the paper's, printing along isolines)."""
