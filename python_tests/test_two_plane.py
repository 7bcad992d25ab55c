"""Two-plane light fields from Python: ``lg.bake_two_plane`` and ``LightField.render`` with
``uv_filter``, ``focus`` and ``aperture`` (DESIGN §9, docs/two_plane.md).

The valid region is recomputed here with numpy from DESIGN §9's text (a pixel ray meets the
closed uv rectangle at t_uv >= 0 and the closed st rectangle beyond it), not from our code: the
renderer must leave every pixel outside it empty (coverage False, depth +inf); f32 against f64
at the region's border may flip a few pixels (allowed: 0.5 %). Quality against the reference
rasterizer over the valid region: the depth-corrected filter within 2 dB or better of bilinear
and above 18 dB masked PSNR at this small size (measured: about 24 dB).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bindings_helpers import design_rays

import lumigraph as lg


@pytest.fixture(scope="module")
def two_plane_lf(demo_mesh: lg.Mesh) -> lg.LightField:
    return lg.bake_two_plane(demo_mesh, grid=(6, 6), st_res=(96, 96), progress=False)


def _view(lf: lg.LightField) -> dict[str, Any]:
    planes = lf.planes
    assert planes is not None
    uv = np.asarray(planes["uv"]["center"], float)
    st = np.asarray(planes["st"]["center"], float)
    eye = uv + 1.0 * (uv - st) + np.array([0.6, -0.4, 0.0])
    return {"eye": eye.tolist(), "target": st.tolist(), "up": [0, 1, 0], "yfov_deg": 50, "width": 64, "height": 56}


def _valid_region(planes: dict[str, Any], view: dict[str, Any]) -> np.ndarray:
    eye, dirs, _ = design_rays(view)
    right = np.asarray(planes["right"], float)
    up = np.asarray(planes["up"], float)
    n = np.cross(right, up)
    along = dirs @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t_uv = (np.asarray(planes["uv"]["center"], float) - eye) @ n / along
        t_st = (np.asarray(planes["st"]["center"], float) - eye) @ n / along

    def inside(t: np.ndarray, rect: dict[str, Any]) -> np.ndarray:
        p = eye + t[:, None] * dirs - np.asarray(rect["center"], float)
        w, h = rect["size"]
        x = p @ right / w + 0.5
        y = 0.5 - p @ up / h
        ok: np.ndarray = (x >= 0) & (x <= 1) & (y >= 0) & (y <= 1)
        return ok

    ok = (t_uv >= 0) & (t_st > t_uv) & inside(t_uv, planes["uv"]) & inside(t_st, planes["st"])
    region: np.ndarray = ok.reshape(view["height"], view["width"])
    return region


def test_bake_two_plane_reports_its_planes_and_round_trips(two_plane_lf: lg.LightField, tmp_path: Path) -> None:
    lf = two_plane_lf
    assert lf.kind == "two_plane"
    assert lf.cameras == 36
    assert lf.resolution == 96
    planes = lf.planes
    assert planes is not None
    assert planes["uv"]["grid"] == [6, 6] and planes["st"]["resolution"] == [96, 96]
    assert lf.info["format_version"] == 5 and lf.info["kind"] == "two_plane"
    path = tmp_path / "tp.lfa"
    lf.save(path)
    again = lg.LightField.open(path)
    assert again.planes == planes
    view = _view(lf)
    a = lf.render(view, uv_filter="bilinear")
    b = again.render(view, uv_filter="bilinear")
    assert np.array_equal(a.color, b.color)
    # The same planes given explicitly capture the same light field.
    explicit = lg.bake_two_plane(lg.Mesh.demo(), planes=planes, progress=False)
    assert np.array_equal(explicit.render(view, uv_filter="bilinear").color, a.color)


@pytest.mark.parametrize("options", [
    {"uv_filter": "nearest"},
    {"uv_filter": "bilinear", "focus": 0.8},
    {"uv_filter": "dither"},
    {"uv_filter": "depth"},
    {"aperture": 1.5, "focus": -0.5, "frame_index": 3},
])
def test_pixels_outside_the_valid_region_are_empty(two_plane_lf: lg.LightField, options: dict[str, Any]) -> None:
    view = _view(two_plane_lf)
    planes = two_plane_lf.planes
    assert planes is not None
    region = _valid_region(planes, view)
    assert 0.2 < region.mean() < 1.0, "the view sees both sides of the region's border"
    frame = two_plane_lf.render(view, **options)
    outside_covered = frame.coverage & ~region
    assert outside_covered.sum() <= 0.005 * region.size
    assert np.isinf(frame.depth[~region & ~frame.coverage]).all()
    assert frame.coverage.sum() > 100
    assert np.array_equal(frame.coverage, np.isfinite(frame.depth))


def test_depth_correction_scores_against_the_reference(two_plane_lf: lg.LightField, demo_mesh: lg.Mesh) -> None:
    view = _view(two_plane_lf)
    planes = two_plane_lf.planes
    assert planes is not None
    region = _valid_region(planes, view)
    reference = lg.reference_render(demo_mesh, view)
    ref_cov = reference.coverage & region
    scores = {}
    for uv_filter in ("bilinear", "depth"):
        frame = two_plane_lf.render(view, uv_filter=uv_filter)
        cov = frame.coverage & region
        scores[uv_filter] = lg.metrics.masked_psnr(
            np.where(cov[..., None], frame.color, 0),
            np.where(ref_cov[..., None], reference.color, 0),
            test_coverage=cov,
            reference_coverage=ref_cov,
        )
    assert scores["depth"] > 18.0, scores
    assert scores["depth"] > scores["bilinear"] - 2.0, scores


def test_bad_two_plane_options_and_planes_raise(two_plane_lf: lg.LightField, demo_lf: lg.LightField) -> None:
    view = _view(two_plane_lf)
    for options in ({"uv_filter": "blurry"}, {"aperture": -1.0}, {"focus": float("nan")}, {"lod": 12}, {"steps": 0}):
        with pytest.raises(ValueError):
            two_plane_lf.render(view, **options)
    with pytest.raises(ValueError):
        demo_lf.render(view, focus=0.5)
    planes = dict(two_plane_lf.planes or {})
    planes["right"] = [2.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="unit"):
        lg.bake_two_plane(lg.Mesh.demo(), planes=planes, progress=False)
    with pytest.raises(ValueError, match="uv grid"):
        lg.bake_two_plane(lg.Mesh.demo(), grid=(64, 64), progress=False)
    with pytest.raises(TypeError):
        lg.bake_two_plane(lg.Mesh.demo(), planes=3, progress=False)  # type: ignore[arg-type]


def test_paged_cache_renders_what_a_resident_one_does_and_reports_its_pages(
    two_plane_lf: lg.LightField, tmp_path: Path
) -> None:
    """`LightField.open(cache_mib=...)` renders through a paged cache: with 2 pages per frame the
    first frames read the coarse level where pages are missing (degraded), later ones load the
    rest, and the last frame equals the frame of a cache that holds every page, bit for bit."""
    path = tmp_path / "tp.lfa"
    two_plane_lf.save(path)
    # A narrow view touches 20 of the 36 pages (one per camera); the cache holds 22.
    view = {**_view(two_plane_lf), "yfov_deg": 15}
    small = lg.LightField.open(path, cache_mib=3.0, prefetch="predict", pages_per_frame=2)
    stats = small.page_stats
    assert stats is not None and stats["last"] is None and stats["summary"]["frames"] == 0
    frames = []
    for _ in range(16):
        frames.append(small.render(view, background=(0, 0, 0)))
        stats = small.page_stats
        assert stats is not None
        if stats["last"]["degraded_px"] == 0:
            break
    assert stats is not None
    first_degraded = len(frames) > 1
    assert first_degraded, "two pages per frame leave the first frame degraded"
    last = stats["last"]
    cache = stats["cache"]
    assert last["degraded_px"] == 0 and last["pages_loaded"] <= 2
    assert last["pages_touched"] <= cache["slots"] < cache["pages"] == 36
    assert cache["device_bytes"] < cache["resident_bytes"]
    summary = stats["summary"]
    assert summary["frames"] == len(frames)
    assert summary["faults"] >= summary["pages_loaded"] > 0
    # Pages are the 96x96 images (one per camera): RGBA8 colour and f32 depth.
    assert summary["bytes_uploaded"] == summary["pages_loaded"] * 96 * 96 * 8
    big = lg.LightField.open(path, cache_mib=64)
    reference = big.render(view, background=(0, 0, 0))
    assert big.page_stats is not None and big.page_stats["last"]["degraded_px"] == 0
    assert np.array_equal(frames[-1].color, reference.color)
    assert np.array_equal(frames[-1].depth, reference.depth)
    assert not np.array_equal(frames[0].color, reference.color), "the coarse level shows"
    # The resident renderer samples with 8-bit bilinear weights (lavapipe), the paged one in f32.
    resident = two_plane_lf.render(view, background=(0, 0, 0)).color.astype(int)
    close = np.abs(resident - reference.color.astype(int)).max(axis=2) <= 2
    assert close.mean() > 0.99
    assert two_plane_lf.page_stats is None


def test_paged_cache_arguments_are_checked(tmp_path: Path, demo_lf: lg.LightField) -> None:
    spherical = tmp_path / "demo.lfa"
    demo_lf.save(spherical)
    with pytest.raises(ValueError, match="two-plane"):
        lg.LightField.open(spherical, cache_mib=4)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="cache_mib"):
            lg.LightField.open(spherical, cache_mib=bad)
    with pytest.raises(ValueError, match="choose none, lru or predict"):
        lg.LightField.open(spherical, cache_mib=4, prefetch="psychic")
    with pytest.raises(ValueError, match="pages_per_frame"):
        lg.LightField.open(spherical, cache_mib=4, pages_per_frame=0)
    with pytest.raises(ValueError, match="give cache_mib"):
        lg.LightField.open(spherical, prefetch="lru")


def _write_grid(folder: Path, grid: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    """Camera images ROW_COL.png with known pixels; returns them as [row, col, y, x, rgba]."""
    from PIL import Image

    folder.mkdir()
    rng = np.random.default_rng(3)
    images = rng.integers(0, 256, size=(grid[1], grid[0], size[1], size[0], 4), dtype=np.uint8)
    images[..., 3] = 255
    for r in range(grid[1]):
        for c in range(grid[0]):
            Image.fromarray(images[r, c], "RGBA").save(folder / f"{r:03d}_{c:03d}.png")
    return images


def test_import_lightfield_grid_in_memory_and_to_a_file(tmp_path: Path) -> None:
    _write_grid(tmp_path / "grid", (3, 2), (16, 12))
    lf = lg.import_lightfield(tmp_path / "grid")
    assert lf.kind == "two_plane"
    assert lf.planes is not None
    assert lf.planes["uv"]["grid"] == [3, 2] and lf.planes["st"]["resolution"] == [16, 12]
    planes = dict(lf.planes)
    planes["st"] = {**planes["st"], "size": [2.0, 1.5]}
    out = tmp_path / "grid.lfa"
    again = lg.import_lightfield(str(tmp_path / "grid"), layout="grid", planes=planes, output=out)
    assert out.is_file() and again.planes is not None
    assert again.planes["st"]["size"] == [2.0, 1.5]
    frame = again.render({"eye": [0, 0, 2.5], "target": [0, 0, 0], "yfov_deg": 60, "width": 32,
                          "height": 24}, uv_filter="nearest")
    assert frame.coverage.any()


def test_import_lightfield_errors_are_clear(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        lg.import_lightfield(tmp_path / "missing")
    _write_grid(tmp_path / "grid", (2, 2), (8, 8))
    with pytest.raises(ValueError, match="layout"):
        lg.import_lightfield(tmp_path / "grid", layout="tiles")
    with pytest.raises(ValueError, match="needs its calibration"):
        lg.import_lightfield(tmp_path / "grid", layout="lenslet")
    with pytest.raises(ValueError, match="planes do not apply"):
        lg.import_lightfield(tmp_path / "grid", layout="lenslet", planes={"right": [1, 0, 0]})
    with pytest.raises(TypeError):
        lg.import_lightfield(tmp_path / "grid", planes=3)  # type: ignore[arg-type]
    (tmp_path / "grid" / "000_000.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="000_000.png"):
        lg.import_lightfield(tmp_path / "grid")


def test_import_lenslet_microscope_image_refocuses(fixtures: Path) -> None:
    """The dev set's light-field microscope image (napari-LF's GUV example): 15 x 15 views of
    26 x 26 lenslets; with the full aperture the vesicle is sharper at the native focal plane
    than 8 um above or below it (gradient energy over the squared mean: measured about 3.5x)."""
    lf = lg.import_lightfield(fixtures / "lightfield" / "GUVExperim1", layout="lenslet")
    planes = lf.planes
    assert planes is not None
    assert planes["uv"]["grid"] == [15, 15] and planes["st"]["resolution"] == [26, 26]
    distance = planes["uv"]["center"][2]
    st = planes["st"]["size"][0]
    view = {"eye": [0, 0, 1.5 * distance], "target": [0, 0, 0],
            "yfov_deg": float(np.degrees(2 * np.arctan(0.45 * st / (1.5 * distance)))),
            "width": 96, "height": 96}

    def energy(focus: float) -> float:
        grey = lf.render(view, aperture=7, focus=focus, refine=8).color[..., :3].astype(float)
        grey = grey.mean(axis=2)
        gx, gy = np.diff(grey, axis=1)[1:-1, :], np.diff(grey, axis=0)[:, 1:-1]
        return float((gx[:, :-1] ** 2 + gy[:-1, :] ** 2).mean() / grey.mean() ** 2)

    sharp = energy(0.0)
    assert sharp > 2.0 * energy(-8.0) and sharp > 2.0 * energy(8.0)
