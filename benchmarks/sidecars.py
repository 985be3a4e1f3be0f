"""Hostile sidecars: prints JSON with the CPU and wall seconds and the memory a refusal
takes, per kind (the 358-byte alias sidecar of eight levels, 5000-deep nesting, a
5000-digit integer), and the length of the message each gives.

    .venv/bin/python benchmarks/sidecars.py

Each kind is loaded in a child process of its own so that its peak RSS is its own.
"""

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

KINDS = {
    "aliases_8_levels": "\n".join(
        ["smooth_mm:", "  - &z [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
        + ["  - &a%d [%s]" % (k, ", ".join(["*" + ("z" if k == 0 else "a%d" % (k - 1))] * 9))
           for k in range(8)]) + "\n",
    "nested_5000": "smooth_mm: " + "[" * 5000 + "]" * 5000 + "\n",
    "integer_5000_digits": "copies: " + "9" * 5000 + "\n",
}

CHILD = """
import json, resource, sys, time
from pipeline.errors import PipelineError
from pipeline.input.sidecar import load_sidecar
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t, c = time.perf_counter(), time.process_time()
try:
    load_sidecar(sys.argv[1])
    code, message = None, ""
except PipelineError as exc:
    code, message = exc.code, str(exc)
print(json.dumps({"code": code, "message_chars": len(message),
                  "wall_s": round(time.perf_counter() - t, 4),
                  "cpu_s": round(time.process_time() - c, 4),
                  "rss_growth_mb": round((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                                          - before) / 1024, 1)}))
"""


def main():
    out = {"loadavg": os.getloadavg()[0]}
    with tempfile.TemporaryDirectory() as tmp:
        for kind, text in KINDS.items():
            path = Path(tmp) / (kind + ".yaml")
            path.write_text(text)
            r = subprocess.run([sys.executable, "-c", CHILD, str(path)], cwd=ROOT,
                               capture_output=True, text=True, timeout=120,
                               env=dict(os.environ, PYTHONPATH=str(ROOT)))
            out[kind] = dict(json.loads(r.stdout), bytes=len(text.encode()))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
