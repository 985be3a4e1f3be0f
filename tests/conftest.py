"""Shared fixtures: the repo root, ../shared (optional), and cached reference meshes."""

import functools
import os
import sys
import tempfile
from pathlib import Path

import pytest

import pipeline  # noqa: F401  (before numpy: it sets the BLAS threads every test runs with)

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
TERRAIN = SHARED / "data" / "terrain"

# The daemons the tests start say where they are in $XDG_RUNTIME_DIR/hostd: a folder of
# the test run's own, so they never replace the pointer of a daemon the user runs.
os.environ["XDG_RUNTIME_DIR"] = tempfile.mkdtemp(prefix="hostd-tests-run-")


def pytest_configure(config):
    """Where bytecode is not written (PYTHONDONTWRITEBYTECODE, as many CI images set), every
    daemon, printer link, planning process and command the tests start compiled hostd and
    pipeline afresh: 0.1-0.3 s of CPU each, a few hundred times a run. They are compiled
    once into pytest's cache folder instead, never beside the sources."""
    cache = getattr(config, "cache", None)       # None with -p no:cacheprovider
    if not sys.dont_write_bytecode or sys.pycache_prefix or cache is None:
        return
    prefix = str(cache.mkdir("pycache"))
    sys.pycache_prefix, sys.dont_write_bytecode = prefix, False
    os.environ["PYTHONPYCACHEPREFIX"] = prefix
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)


@pytest.fixture
def terrain_dir():
    """../shared/data/terrain, or skip where this clone has no ../shared."""
    if not TERRAIN.is_dir():
        pytest.skip("../shared/data/terrain is not present beside this clone")
    return TERRAIN


@functools.lru_cache(maxsize=None)
def reference_mesh(name, **kwargs):
    """Mesh of a synthetic reference shape (cached across tests in one run)."""
    from pipeline.input import shapes
    from pipeline.meshing.isoline import build_mesh
    return build_mesh(shapes.REFERENCE[name](), **kwargs)


@functools.lru_cache(maxsize=None)
def reference_flat(name):
    """(mesh, FlatResult) of a synthetic reference shape with the paper's defaults."""
    from pipeline.layout.isoline import flatten
    mesh = reference_mesh(name)
    return mesh, flatten(mesh)


@functools.lru_cache(maxsize=None)
def reference_toolpaths(name, path_width_mm=0.48):
    """(mesh, FlatResult, Toolpaths) of a synthetic reference shape."""
    from pipeline.paths.isoline import plan_toolpaths
    mesh, flat = reference_flat(name)
    tp = plan_toolpaths(flat.xy, mesh.faces, mesh.vertex_level, mesh.printing_edges,
                        flat.sigma, path_width_mm)
    return mesh, flat, tp


@pytest.fixture(scope="module")
def dome(tmp_path_factory):
    """A small dome drop file with its sidecar, for the daemon's end-to-end tests."""
    from daemon_helpers import write_dome
    return write_dome(tmp_path_factory.mktemp("inputs") / "dome.npy")


@pytest.fixture
def pty_sim():
    """(simulator, port path): a simulated printer on a real pty in this process."""
    from daemon_helpers import pty_simulator
    with pty_simulator() as sim_and_port:
        yield sim_and_port


def pytest_collection_modifyitems(items):
    """Files holding slow tests run first. The two workers take whole files in the
    order collected; a minute-long file taken last keeps one of them busy while the
    other idles. Tests keep their order within a file."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    order = {id(item): k for k, item in enumerate(items)}
    items.sort(key=lambda item: (item.path not in slow_files, order[id(item)]))
