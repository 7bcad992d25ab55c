"""Every bad argument gets a typed error whose message says what to fix."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bindings_helpers import icosphere_arrays

import lumigraph as lg

VIEW: dict[str, Any] = {"eye": [0, 0, 3], "target": [0, 0, 0], "yfov_deg": 40, "width": 32, "height": 32}
V, F = icosphere_arrays(1)


@pytest.fixture(scope="module")
def lf() -> lg.LightField:
    return lg.bake_mesh(lg.Mesh.demo(), cameras=12, resolution=16, progress=False)


def test_error_hierarchy() -> None:
    for cls in (lg.AssetError, lg.BakeError, lg.RenderError):
        assert issubclass(cls, lg.LumigraphError) and issubclass(cls, Exception)
    assert issubclass(lg.MeshError, ValueError)


@pytest.mark.parametrize(
    ("change", "error", "match"),
    [
        ({"eye": [0, 0, 0]}, ValueError, "eye and target coincide"),
        ({"up": [0, 0, 1]}, ValueError, "up vector"),
        ({"up": [0, 0, 0]}, ValueError, "up vector"),
        ({"yfov_deg": 0}, ValueError, "yfov_deg"),
        ({"yfov_deg": 180}, ValueError, "yfov_deg"),
        ({"width": 0}, ValueError, "view size"),
        ({"height": 9000}, ValueError, "view size"),
        ({"width": -1}, TypeError, "width"),
        ({"width": 32.5}, TypeError, "width"),
        ({"eye": [0, 0]}, TypeError, "eye"),
        ({"eye": "abc"}, TypeError, "eye"),
        ({"target": [0, float("nan"), 0]}, ValueError, "target"),
        ({"colour": 1}, ValueError, "unknown view field `colour`"),
    ],
)
def test_bad_views(lf: lg.LightField, change: dict[str, Any], error: type[Exception], match: str) -> None:
    view = {**VIEW, **change}
    with pytest.raises(error, match=match):
        lf.render(view)
    with pytest.raises(error, match=match):
        lg.reference_render((V, F), view)


def test_bad_view_types(lf: lg.LightField) -> None:
    with pytest.raises(TypeError, match="a view must be a lumigraph.View or a dict"):
        lf.render([0, 0, 3])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="missing the field `yfov_deg`"):
        lf.render({k: v for k, v in VIEW.items() if k != "yfov_deg"})
    with pytest.raises(TypeError, match="list of views"):
        lf.render_many(VIEW)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="iterable"):
        lf.render_many(3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="invalid view JSON"):
        lg.View.from_json("{not json")
    with pytest.raises(TypeError):
        lg.View([0, 0, 3], [0, 0, 0], 40, 32, 32)  # type: ignore[misc]  # keyword-only


@pytest.mark.parametrize(
    ("options", "error", "match"),
    [
        ({"lod": 162}, ValueError, "exceeds the asset's 12 cameras"),
        ({"lod": 13}, ValueError, "lod 13"),
        ({"lod": -1}, ValueError, "`lod`"),
        ({"step": 0.0}, ValueError, "step"),
        ({"step": 2.0}, ValueError, "step"),
        ({"step": float("nan")}, ValueError, "step"),
        ({"tolerance": 0.0}, ValueError, "tolerance"),
        ({"method": "fast"}, ValueError, "unknown method `fast`"),
        ({"background": (0, 0, 256)}, ValueError, "background"),
        ({"background": (0, 0)}, ValueError, "background"),
        ({"background": "white"}, TypeError, "background"),
        ({"step": "fine"}, ValueError, "`step`"),
    ],
)
def test_bad_render_options(lf: lg.LightField, options: dict[str, Any], error: type[Exception], match: str | None) -> None:
    with pytest.raises(error, match=match):
        lf.render(VIEW, **options)
    with pytest.raises(error, match=match):
        lf.render_many([VIEW], **options)


def test_render_options_are_keyword_only(lf: lg.LightField) -> None:
    with pytest.raises(TypeError):
        lf.render(VIEW, 12)  # type: ignore[misc]
    with pytest.raises(TypeError):
        lg.bake_mesh((V, F), 12)  # type: ignore[misc]


@pytest.mark.parametrize(
    ("options", "error", "match"),
    [
        ({"cameras": 100}, ValueError, "cameras=100 is not an icosphere camera count"),
        ({"resolution": 4}, ValueError, "resolution 4 px"),
        ({"resolution": 5000}, ValueError, "resolution 5000 px"),
        ({"depth_bits": 12}, ValueError, "depth bits 12"),
        ({"ambient": 1.5}, ValueError, "ambient"),
        ({"light": (0, 0, 0)}, ValueError, "light direction"),
        ({"light": (0, 1)}, ValueError, "length 3"),
        ({"specular": (2.0, 10.0)}, ValueError, "specular"),
        ({"specular": (0.5, 0.0)}, ValueError, "specular"),
        ({"progress": "yes"}, TypeError, "progress"),
        ({"cameras": "many"}, TypeError, "cameras"),
    ],
)
def test_bad_bake_options(options: dict[str, Any], error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        lg.bake_mesh((V, F), **{"cameras": 12, "resolution": 16, "progress": False, **options})


def test_bad_shading_in_reference_render() -> None:
    with pytest.raises(ValueError, match="ambient"):
        lg.reference_render((V, F), VIEW, ambient=-0.1)


@pytest.mark.parametrize(
    ("mesh", "error", "match"),
    [
        ((V, F.astype(np.float64)), TypeError, "faces must be an integer array"),
        ((V, F[:, :2]), ValueError, r"faces must have shape \(M, 3\)"),
        ((V[:, :2], F), ValueError, r"vertices must have shape \(N, 3\), got \(\d+, 2\)"),
        ((V.astype(str), F), TypeError, "vertices must hold real numbers"),
        ((V, F + len(V)), lg.MeshError, "refers to vertex"),
        ((V, -F - 1), ValueError, "indices must be in 0..2\\*\\*32"),
        ((np.where(np.arange(len(V))[:, None] == 3, np.nan, V), F), lg.MeshError, "non-finite"),
        ((V, F[:0]), lg.MeshError, "no triangles"),
        ((np.zeros_like(V), F), lg.MeshError, "degenerate"),
        ((V, F, np.zeros((len(V), 2))), ValueError, r"colors must have shape \(N, 3\) or \(N, 4\)"),
        ((V, F, np.full((len(V), 3), 2.0)), ValueError, "outside \\[0, 1\\]"),
        ((V, F, np.full((len(V), 3), 2, dtype=np.int32)), TypeError, "uint8"),
        ((V, F, np.zeros((len(V) - 1, 3))), lg.MeshError, "colors"),
        (42, TypeError, "mesh must be a lumigraph.Mesh"),
        ((V,), TypeError, "mesh must be"),
    ],
)
def test_bad_meshes(mesh: Any, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        lg.as_mesh(mesh)


def test_texture_without_uvs_and_bad_texture() -> None:
    with pytest.raises(ValueError, match="a texture needs uvs"):
        lg.Mesh(V, F, texture=np.zeros((4, 4, 3), np.uint8))
    uvs = np.zeros((len(V), 2))
    with pytest.raises(ValueError, match=r"texture must be an image of shape \(H, W, 3\)"):
        lg.Mesh(V, F, uvs=uvs, texture=np.zeros((4, 4), np.uint8))
    with pytest.raises(TypeError, match="texture must be uint8"):
        lg.Mesh(V, F, uvs=uvs, texture=np.zeros((4, 4, 3), np.int16))


def test_non_contiguous_and_other_dtypes_are_converted() -> None:
    v64 = np.asfortranarray(V)  # float64, Fortran order
    f32 = np.repeat(F.astype(np.uint16), 2, axis=0)[::2]  # a non-contiguous view, unsigned
    assert not f32.flags.c_contiguous
    mesh = lg.Mesh(v64, f32, np.asarray(np.full((len(V), 4), 0.5), order="F"))
    np.testing.assert_array_equal(mesh.faces, F)
    np.testing.assert_allclose(mesh.vertices, V.astype(np.float32))
    lists = lg.Mesh(V.tolist(), F.tolist())
    np.testing.assert_array_equal(lists.faces, mesh.faces)


def test_missing_corrupt_and_unwritable_assets(lf: lg.LightField, tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no such light-field asset"):
        lg.LightField.open(tmp_path / "missing.lfa")
    junk = tmp_path / "junk.lfa"
    junk.write_bytes(b"PK\x03\x04 this is a zip file, not an asset" * 10)
    with pytest.raises(lg.AssetError, match="not a lumigraph light-field asset"):
        lg.LightField.open(junk)
    data = lf.to_bytes()
    truncated = tmp_path / "truncated.lfa"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(lg.AssetError, match="truncated"):
        lg.LightField.open(truncated)
    with pytest.raises(lg.AssetError, match="cannot write"):
        lf.save(tmp_path / "no" / "such" / "dir" / "x.lfa")
    with pytest.raises(TypeError):
        lg.LightField.from_bytes("not bytes")  # type: ignore[arg-type]
    # A page corrupted after open: AssetError names the page, on verify and on render.
    path = tmp_path / "ok.lfa"
    lf.save(path)
    opened = lg.LightField.open(path)
    blob = bytearray(data)
    blob[200] ^= 0xFF  # inside the first page's compressed bytes
    path.write_bytes(bytes(blob))
    with pytest.raises(lg.AssetError):
        opened.verify()


def test_missing_mesh_file_and_unknown_format(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no such mesh file"):
        lg.bake_mesh(tmp_path / "missing.obj", progress=False)
    bad = tmp_path / "mesh.xyz"
    bad.write_text("1 2 3\n")
    with pytest.raises(lg.MeshError, match="unknown mesh format"):
        lg.as_mesh(bad)
    broken = tmp_path / "broken.off"
    broken.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n")
    with pytest.raises(lg.MeshError, match="malformed"):
        lg.as_mesh(broken)


def test_metric_argument_errors() -> None:
    a = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(ValueError, match="image sizes differ"):
        lg.metrics.psnr(a, np.zeros((8, 9, 3), np.uint8))
    with pytest.raises(TypeError, match="must be uint8"):
        lg.metrics.psnr(a.astype(np.float32), a)
    with pytest.raises(ValueError, match=r"shape \(H, W, 3\)"):
        lg.metrics.ssim(a[..., 0], a[..., 0])
    with pytest.raises(ValueError, match="smaller than the 7x7 SSIM window"):
        lg.metrics.ssim(a[:5, :5], a[:5, :5])
    with pytest.raises(TypeError, match="boolean"):
        lg.metrics.psnr(a, a, mask=np.ones((8, 8)))
    with pytest.raises(ValueError, match=r"expected \(8, 8\)"):
        lg.metrics.psnr(a, a, mask=np.ones((4, 4), bool))
    with pytest.raises(TypeError, match="needs test_coverage"):
        lg.metrics.masked_psnr(a, a)
    with pytest.raises(TypeError, match="float depth"):
        lg.metrics.depth_error(np.zeros((4, 4), np.int32), np.zeros((4, 4), np.int32))
    with pytest.raises(TypeError, match="lumigraph.Frame"):
        lg.metrics.compare(a, a)  # type: ignore[arg-type]
