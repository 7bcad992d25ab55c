"""trimesh input: vertex colours, face colours and texture visuals are honoured, and agree with
the same mesh exported to a file and loaded by lumigraph's own loaders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lumigraph as lg

trimesh = pytest.importorskip("trimesh")
PIL = pytest.importorskip("PIL.Image")

VIEW = {"eye": [0.4, 0.8, 2.8], "target": [0, 0, 0], "yfov_deg": 45, "width": 96, "height": 96}


def test_vertex_colours_equal_the_arrays() -> None:
    tm = trimesh.creation.icosphere(subdivisions=3)
    colors = ((tm.vertices * 0.5 + 0.5) * 255).astype(np.uint8)
    tm.visual.vertex_colors = colors
    a = lg.reference_render(tm, VIEW, unlit=True)
    b = lg.reference_render((tm.vertices, tm.faces, colors), VIEW, unlit=True)
    np.testing.assert_array_equal(a.color, b.color)
    covered = a.color[a.coverage][:, :3].astype(int)
    assert covered.std(axis=0).min() > 20  # colourful, not the default grey


def test_face_colours_are_honoured() -> None:
    tm = trimesh.creation.icosphere(subdivisions=1)
    rng = np.random.default_rng(0)
    palette = rng.integers(0, 256, size=(len(tm.faces), 4), dtype=np.uint8)
    palette[:, 3] = 255
    tm.visual.face_colors = palette
    frame = lg.reference_render(tm, VIEW, unlit=True)
    seen = frame.color[frame.coverage][:, :3].astype(int)
    # Unlit: every covered pixel shows one face's colour exactly (within 8-bit rounding).
    dist = np.abs(seen[:, None, :] - palette[None, :, :3].astype(int)).max(axis=2).min(axis=1)
    assert np.mean(dist <= 1) > 0.999


def spherical_uv(vertices: np.ndarray) -> np.ndarray:
    u = np.arctan2(vertices[:, 0], vertices[:, 2]) / (2 * np.pi) + 0.5
    v = np.arcsin(np.clip(vertices[:, 1], -1, 1)) / np.pi + 0.5  # trimesh: v up
    return np.column_stack([u, v])


@pytest.mark.parametrize("material", ["simple", "pbr"])
def test_texture_visuals_match_the_obj_loader(tmp_path: Path, material: str) -> None:
    tm = trimesh.creation.icosphere(subdivisions=4)
    h, w = 32, 64
    yy, xx = np.mgrid[0:h, 0:w]
    image = np.zeros((h, w, 3), np.uint8)
    image[..., 0] = (xx * 255 // (w - 1)).astype(np.uint8)  # red grows with u
    image[..., 2] = np.where(yy < h // 2, 230, 20)  # blue on top rows = v high (trimesh)
    image[..., 1] = np.where((xx // 8 + yy // 8) % 2 == 0, 200, 40)
    pil = PIL.fromarray(image)
    if material == "simple":
        mat = trimesh.visual.material.SimpleMaterial(image=pil, diffuse=[255, 255, 255, 255])
    else:
        mat = trimesh.visual.material.PBRMaterial(baseColorTexture=pil, baseColorFactor=[255, 255, 255, 255])
    tm.visual = trimesh.visual.TextureVisuals(uv=spherical_uv(tm.vertices), material=mat)
    ours = lg.reference_render(tm, VIEW, unlit=True)
    covered = ours.color[ours.coverage][:, :3].astype(int)
    assert covered[:, 0].std() > 10 and covered[:, 1].std() > 30  # texture visible

    # Looking down on the north pole (v high in trimesh = top image rows = blue 230).
    top = {"eye": [0, 3, 0.01], "target": [0, 0, 0], "yfov_deg": 20, "width": 32, "height": 32}
    north = lg.reference_render(tm, top, unlit=True)
    assert north.color[north.coverage][:, 2].mean() > 200

    if material == "simple":
        obj = tmp_path / "sphere.obj"
        tm.export(obj)
        loaded = lg.reference_render(obj, VIEW, unlit=True)
        np.testing.assert_array_equal(loaded.coverage, ours.coverage)
        # The OBJ stores uvs as decimal text: allow rounding-level differences.
        assert lg.metrics.psnr(loaded, ours) > 40
        assert lg.metrics.mae(loaded, ours) < 0.5


def test_scenes_are_rejected_with_a_hint() -> None:
    scene = trimesh.Scene([trimesh.creation.box()])
    with pytest.raises(TypeError, match="force='mesh'"):
        lg.as_mesh(scene)
