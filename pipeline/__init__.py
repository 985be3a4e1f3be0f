"""Flatten-and-plan pipeline for 4D printing of height fields (pure computation).

Arrays in, arrays out: nothing here imports ``hostd``.
"""

__version__ = "0.1.0"
