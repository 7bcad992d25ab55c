"""Shared fixtures of the Python binding tests.

GPU work is kept small (12-42 cameras, maps <= 128 px, views <= 128 px) so that the suite stays
fast on Mesa lavapipe (CPU). The real-mesh fixtures come from scripts/fixtures.sh into
$LUMIGRAPH_FIXTURES or ./fixtures, fetched on first use like the Rust tests do.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from bindings_helpers import fixtures_dir, orbit

import lumigraph as lg


@pytest.fixture(scope="session")
def fixtures() -> Path:
    return fixtures_dir()


@pytest.fixture(scope="session")
def demo_mesh() -> lg.Mesh:
    return lg.Mesh.demo()


@pytest.fixture(scope="session")
def demo_lf(demo_mesh: lg.Mesh) -> lg.LightField:
    """The demo trefoil at 42 cameras, 96-px maps."""
    return lg.bake_mesh(demo_mesh, cameras=42, resolution=96, progress=False)


@pytest.fixture(scope="session")
def demo_views(demo_mesh: lg.Mesh) -> list[lg.View]:
    center, radius = demo_mesh.bounding_sphere
    return orbit(center, radius, 4, size=96)
