"""Plain helpers of the binding tests (a module name of its own: python_tests/service has its
own conftest.py, so tests import helpers from here, never from `conftest`)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import lumigraph as lg

ROOT = Path(__file__).resolve().parent.parent
FIXTURE_FILES = (
    "mesh/bunny00.off",
    "mesh/cow.off",
    "mesh/spot.ply",
    "volume/mni_t1.nii.gz",
    "anim/AnimatedMorphCube.gltf",
    "anim/AnimatedMorphCube.bin",
    "anim/simple_skin.gltf",
    "lightfield/GUVExperim1/Lightfield_GUVExperim1.tif",
    "lightfield/GUVExperim1/DarkFrame_GUVExperim1.tif",
    "lightfield/GUVExperim1/Radiometry_GUVExperim1.tif",
    "lightfield/GUVExperim1/metadata.txt",
)


def fixtures_dir() -> Path:
    """$LUMIGRAPH_FIXTURES or <repo>/fixtures, filled by scripts/fixtures.sh when incomplete."""
    folder = Path(os.environ.get("LUMIGRAPH_FIXTURES") or ROOT / "fixtures")
    if all((folder / f).is_file() for f in FIXTURE_FILES):
        return folder
    script = ROOT / "scripts" / "fixtures.sh"
    result = subprocess.run(
        ["bash", str(script), str(folder)], capture_output=True, text=True, check=False
    )
    if result.returncode != 0 or not all((folder / f).is_file() for f in FIXTURE_FILES):
        pytest.fail(
            f"cannot fetch the dev fixtures with {script} into {folder} "
            f"(needs apt-get and pip with registry access):\n{result.stdout}\n{result.stderr}"
        )
    return folder


def orbit(center: Any, radius: float, n: int, *, size: int = 96, seed: int = 0) -> list[lg.View]:
    """The CLI eval's views: eye on a sphere of 2.5x the bounding radius, 40 degrees."""
    return lg.orbit_views(center, 2.5 * radius, n, seed=seed, yfov_deg=40.0, size=size)


def icosphere_arrays(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A unit icosphere (vertices, faces) made with numpy only."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = [
        (-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0),
        (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
        (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1),
    ]  # fmt: skip
    f = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    verts = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in v]
    faces = list(f)
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return np.array(verts), np.array(faces, dtype=np.int64)


def design_rays(view: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit ray directions (H*W, 3) and the forward axis, from DESIGN §3's formulas."""
    eye = np.asarray(view["eye"], float)
    forward = np.asarray(view["target"], float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(view["up"], float))
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    h, w = view["height"], view["width"]
    f = (h / 2) / np.tan(np.radians(view["yfov_deg"]) / 2)
    j, i = np.meshgrid(np.arange(w), np.arange(h))
    x = (j + 0.5 - w / 2) / f
    y = -(i + 0.5 - h / 2) / f
    d = x[..., None] * right + y[..., None] * true_up + forward
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return eye, d.reshape(-1, 3), forward
