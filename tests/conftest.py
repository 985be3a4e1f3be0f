"""Shared fixtures: the repo root, ../shared (optional), and cached reference meshes."""

import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
TERRAIN = SHARED / "data" / "terrain"


@pytest.fixture
def terrain_dir():
    """../shared/data/terrain, or skip where this clone has no ../shared."""
    if not TERRAIN.is_dir():
        pytest.skip("../shared/data/terrain is not present beside this clone")
    return TERRAIN


@functools.lru_cache(maxsize=None)
def reference_mesh(name, **kwargs):
    """Mesh of a synthetic reference shape (cached across tests in one run)."""
    from pipeline import shapes
    from pipeline.mesh import build_mesh
    return build_mesh(shapes.REFERENCE[name](), **kwargs)
