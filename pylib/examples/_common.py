"""Helpers shared by the examples: where the dev-fixture meshes are, and small stand-ins."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh


def fixture_meshes() -> list[Path]:
    """The dev-fixture meshes ($LUMIGRAPH_FIXTURES or ./fixtures), if fetched."""
    root = Path(os.environ.get("LUMIGRAPH_FIXTURES") or "fixtures") / "mesh"
    return sorted(p for p in root.glob("*") if p.suffix in {".off", ".ply", ".obj", ".glb", ".stl"})


def write_stand_in_meshes(folder: Path) -> list[Path]:
    """Two small coloured meshes, for when no fixtures are around."""
    folder.mkdir(parents=True, exist_ok=True)
    sphere = trimesh.creation.icosphere(subdivisions=3)
    sphere.visual.vertex_colors = ((sphere.vertices * 0.5 + 0.5) * 255).astype(np.uint8)
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35)
    paths = [folder / "sphere.ply", folder / "torus.ply"]
    sphere.export(paths[0])
    torus.export(paths[1])
    return paths
