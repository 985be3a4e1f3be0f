"""The pipeline's processes run BLAS on one thread unless the user sets it."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_pipeline_runs_blas_on_one_thread_unless_told_otherwise():
    """Many small solves: extra OpenBLAS threads only spin-wait, and on a busy host each
    waits for a descheduled thread (a Delaunay point location took 14 s, not 5 ms)."""
    code = ("import os, pipeline, numpy\n"
            "print(os.environ['OPENBLAS_NUM_THREADS'], os.environ['OMP_NUM_THREADS'])\n")
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout.split()
    assert out == ["1", "1"]
    env["OPENBLAS_NUM_THREADS"] = "4"
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout.split()
    assert out == ["4", "1"]
