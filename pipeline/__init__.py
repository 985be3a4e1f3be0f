"""Flatten-and-plan pipeline for 4D printing of height fields (pure computation).

Arrays in, arrays out: nothing here imports ``hostd``.
"""

import os

__version__ = "0.1.0"

# One BLAS thread unless the user says otherwise. The plan's dense linear algebra is many
# small solves (per-triangle transforms, point location), where OpenBLAS's extra threads
# only spin-wait; on a host with other work (the daemon, a second plan, a test worker)
# each call then waits for a descheduled thread: scipy's Delaunay point location took
# 14 s instead of 5 ms with two threads on two busy cores. Read when the library loads,
# so this must run before numpy is imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
