"""Layout: the flat sheet to print and each region's shrink. One module per method
(``isoline``: the paper's, printing along isolines; ``free``), and the stages of a plan
by each (``isoline_method``, ``free_method``), found by name in ``method``."""
