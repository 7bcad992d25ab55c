"""``lg.reference_volume`` (the direct ray cast of DESIGN §9) against a ray caster written here
from DESIGN §9's text with numpy and scipy (``map_coordinates(order=1, mode="nearest")`` is
trilinear sampling with the index clamped to the edge voxels), not from our code.

Tolerances, and why: both work in float64 on the same float32 voxels, so premultiplied colour
and opacity agree to about 1e-12; the 8-bit frame (straight colour ``round(255·C/A)``, alpha
``round(255·A)``) may then differ by one level where a value lies within that of a rounding edge
(allowed: 1 level, on at most 1 % of the channels). Depths come from the same sample, so they
agree to 1e-9 relative where both are finite, and are infinite at the same pixels.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
from bindings_helpers import design_rays
from scipy import ndimage

import lumigraph as lg

TF = {"points": [[0.0, 0.1, 0.2, 0.9, 0.0], [0.4, 0.9, 0.6, 0.2, 0.35], [1.0, 1.0, 1.0, 1.0, 0.9]]}
VIEW = {"eye": [9.0, 6.0, -8.0], "target": [3.0, 3.0, 4.0], "up": [0, 1, 0], "yfov_deg": 45, "width": 28, "height": 22}


def tf_eval(points: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(values, points[:, 0], points[:, c]) for c in range(1, 5)], axis=-1)


def _over_black(color: np.ndarray) -> np.ndarray:
    """A straight-colour RGBA8 frame composited over black, as float levels."""
    return color[..., :3].astype(float) * color[..., 3:4] / 255.0


def numpy_raycast(
    vol: np.ndarray, spacing: np.ndarray, origin: np.ndarray, view: dict, shade: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Premultiplied RGBA (H, W, 4) and depth (H, W): DESIGN §9 for a diagonal affine."""
    points = np.asarray(TF["points"], float)
    ref_step = spacing.min()
    step = ref_step / 2
    light = np.array([0.3, 1.0, 0.5]) / np.linalg.norm([0.3, 1.0, 0.5])
    ambient = 0.25
    dims_xyz = np.array(vol.shape[::-1], float)
    data = vol.astype(np.float64)
    value_range = data.max() - data.min()

    def sample(world: np.ndarray) -> np.ndarray:
        u = (world - origin) / spacing  # index (i, j, k)
        return ndimage.map_coordinates(data, [u[:, 2], u[:, 1], u[:, 0]], order=1, mode="nearest")

    eye, flat_dirs, forward = design_rays(view)
    h, w = view["height"], view["width"]
    dirs = flat_dirs.reshape(h, w, 3)
    rgba = np.zeros((h, w, 4))
    depth = np.full((h, w), np.inf)
    lo = origin - 0.5 * spacing
    hi = origin + (dims_xyz - 0.5) * spacing
    for y in range(h):
        for x in range(w):
            d = dirs[y, x]
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (lo - eye) / d, (hi - eye) / d
            t_in = np.max(np.minimum(t1, t2))
            t_out = np.min(np.maximum(t1, t2))
            t0 = max(t_in, 0.0)
            if not t0 < t_out:
                continue
            t = t0 + (np.arange(int(np.ceil((t_out - t0) / step)) + 1) + 0.5) * step
            t = t[t < t_out]
            if len(t) == 0:
                continue
            p = eye + t[:, None] * d
            c = tf_eval(points, sample(p))
            alpha = 1 - (1 - c[:, 3]) ** (step / ref_step)
            rgb = c[:, :3]
            if shade:
                grad = np.stack(
                    [(sample(p + e * s) - sample(p - e * s)) / (2 * s) for e, s in zip(np.eye(3), spacing)], axis=-1
                )
                norm = np.linalg.norm(grad, axis=-1)
                factor = ambient + (1 - ambient) * np.abs(grad @ light) / np.where(norm > 0, norm, 1)
                flat = (norm * spacing.min() < 1e-6 * value_range) | (norm == 0)
                rgb = rgb * np.where(flat, 1.0, factor)[:, None]
            transmit = np.concatenate([[1.0], np.cumprod(1 - alpha)])
            acc = 1 - transmit[1:]
            stop = np.nonzero(acc >= 0.995)[0]
            n = stop[0] + 1 if len(stop) else len(alpha)
            weights = transmit[:n] * alpha[:n]
            rgba[y, x, :3] = weights @ rgb[:n]
            rgba[y, x, 3] = acc[n - 1]
            reached = np.nonzero(acc[:n] >= 0.5)[0]
            if len(reached):
                depth[y, x] = t[reached[0]] * d @ forward
    return rgba, depth


def to_8bit(rgba: np.ndarray) -> np.ndarray:
    a = rgba[..., 3]
    alpha = np.clip(np.round(255 * a), 0, 255)
    with np.errstate(divide="ignore", invalid="ignore"):
        straight = np.clip(np.round(255 * rgba[..., :3] / a[..., None]), 0, 255)
    straight[alpha < 1] = 0
    return np.concatenate([straight, alpha[..., None]], axis=-1).astype(np.uint8)


@pytest.mark.parametrize("shade", [False, True])
def test_matches_an_independent_numpy_ray_caster(shade: bool) -> None:
    rng = np.random.default_rng(7)
    vol = ndimage.gaussian_filter(rng.random((12, 10, 8)), 1.2).astype(np.float32)
    vol = (vol - vol.min()) / (vol.max() - vol.min())
    spacing = np.array([0.75, 1.0, 0.5])
    origin = np.array([1.0, -2.0, 0.5])
    frame = lg.reference_volume(vol, VIEW, tf=TF, spacing=tuple(spacing), origin=tuple(origin), shade=shade)
    rgba, depth = numpy_raycast(vol, spacing, origin, VIEW, shade)
    want = to_8bit(rgba)
    got = frame.color.astype(int)
    diff = np.abs(got - want.astype(int))
    assert (rgba[..., 3] > 0.05).sum() > 100, "the volume fills a good part of the frame"
    assert diff.max() <= 1 and (diff > 0).mean() <= 0.01, f"max {diff.max()}, {(diff > 0).mean():.4f} differ"
    assert np.array_equal(np.isfinite(frame.depth), np.isfinite(depth))
    finite = np.isfinite(depth)
    assert finite.sum() > 20
    np.testing.assert_allclose(frame.depth[finite], depth[finite], rtol=1e-6)


def test_a_file_and_its_array_render_the_same(fixtures: Path) -> None:
    path = fixtures / "volume" / "mni_t1.nii.gz"
    view = {"eye": [0, 300, 0], "target": [0, -18, 22], "up": [0, 0, 1], "yfov_deg": 45, "width": 40, "height": 40}
    from_file = lg.reference_volume(path, view, tf="mri-brain", shade=True)
    raw = gzip.decompress(path.read_bytes())[352:]
    array = np.frombuffer(raw, np.uint8).reshape(189, 233, 197)
    from_array = lg.reference_volume(array, view, tf="mri-brain", shade=True, origin=(-98, -134, -72))
    assert np.array_equal(from_file.color, from_array.color)
    covered = (from_file.color[..., 3] > 0).mean()
    assert 0.1 < covered < 0.7, covered


def test_bad_input_is_refused() -> None:
    ball = np.zeros((4, 4, 4), np.float32)
    view = {"eye": [1.5, 1.5, -5], "target": [1.5, 1.5, 1.5], "up": [0, 1, 0], "yfov_deg": 40, "width": 4, "height": 4}
    nan = ball.copy()
    nan[1, 2, 3] = np.nan
    with pytest.raises(ValueError, match=r"i=3, j=2, k=1"):
        lg.reference_volume(nan, view, tf=TF)
    with pytest.raises(ValueError, match="3-D"):
        lg.reference_volume(np.zeros((4, 4)), view, tf=TF)
    with pytest.raises(ValueError, match="labels must be"):
        lg.reference_volume(-np.ones((2, 2, 2), np.int32), view, tf={"labels": {"1": [1, 0, 0, 1]}}, labels=True)
    with pytest.raises(TypeError, match="integers"):
        lg.reference_volume(ball, view, tf={"labels": {"1": [1, 0, 0, 1]}}, labels=True)
    with pytest.raises(ValueError, match="neither a preset"):
        lg.reference_volume(ball, view, tf="ct-lung")
    with pytest.raises(ValueError, match="scalar transfer function"):
        lg.reference_volume(ball, view, tf={"labels": {"1": [1, 0, 0, 1]}})
    with pytest.raises(ValueError, match="sorted"):
        lg.reference_volume(ball, view, tf={"points": [[1, 0, 0, 0, 0], [0, 0, 0, 0, 0]]})
    with pytest.raises(ValueError, match="singular"):
        lg.reference_volume(ball, view, tf=TF, spacing=(0, 1, 1))
    with pytest.raises(ValueError, match="spacing needs 3"):
        lg.reference_volume(ball, view, tf=TF, spacing=(1, 1))
    with pytest.raises(ValueError, match="step"):
        lg.reference_volume(ball, view, tf=TF, step=-1)
    with pytest.raises(FileNotFoundError):
        lg.reference_volume("/nonexistent/head.nii.gz", view, tf="mri-brain")
    with pytest.raises(ValueError, match="origin applies to arrays"):
        lg.reference_volume("/nonexistent/head.nii.gz", view, tf="mri-brain", origin=(0, 0, 0))


def _blob() -> np.ndarray:
    rng = np.random.default_rng(3)
    vol = ndimage.gaussian_filter(rng.random((20, 18, 16)), 2.0)
    z, y, x = np.mgrid[:20, :18, :16]
    ball = np.sqrt(((z - 9.5) / 9) ** 2 + ((y - 8.5) / 8) ** 2 + ((x - 7.5) / 7) ** 2)
    return ((1 - ball).clip(0, 1) * (0.6 + vol)).astype(np.float32)


def test_bake_volume_renders_close_to_the_direct_ray_cast(tmp_path: Path) -> None:
    """A baked volume light field against ``reference_volume`` over black: 42 cameras of 64 px
    on a 64² view of a soft blob (the CLI and Rust suites hold every baked texel to the CPU ray
    cast; here the fronts agree end to end). Measured about 30 dB full-frame PSNR over black and
    an MAE near 2 levels; a lost premultiplication, transfer function or shading costs 10 dB."""
    vol = _blob()
    tf = {"points": [[0.0, 0, 0, 0, 0], [0.1, 0.2, 0.5, 0.9, 0.05], [0.5, 1, 0.8, 0.4, 0.8]]}
    seen: list[tuple[int, int]] = []
    lf = lg.bake_volume(
        vol, tf=tf, spacing=(0.8, 1.0, 1.2), shade=True, cameras=42, resolution=64, progress=lambda d, t: seen.append((d, t))
    )
    assert seen and seen[-1] == (42, 42)
    assert lf.cameras == 42 and lf.info["geometry"]["camera_count"] == 42
    view = {"eye": [30.0, 14.0, -20.0], "target": [6.0, 8.5, 11.4], "up": [0, 1, 0], "yfov_deg": 40, "width": 64, "height": 64}
    frame = lf.render(view)
    truth = lg.reference_volume(vol, view, tf=tf, spacing=(0.8, 1.0, 1.2), shade=True)

    a, b = _over_black(frame.color), _over_black(truth.color)
    mse = ((a - b) ** 2).mean()
    psnr = 10 * np.log10(255.0**2 / mse)
    assert (truth.color[..., 3] > 0).mean() > 0.1, "the blob fills the view"
    assert psnr > 26.0, f"PSNR over black {psnr:.2f} dB"
    assert np.abs(a - b).mean() < 4.0
    # Depth only where the opacity reached τ_d = 0.5, as in the reference.
    assert np.array_equal(np.isfinite(frame.depth), frame.color[..., 3] >= 128)
    # Saved and reopened: the same frame.
    path = tmp_path / "blob.lfa"
    lf.save(path)
    again = lg.LightField.open(path).render(view)
    assert np.array_equal(again.color, frame.color)


def test_bake_volume_refuses_bad_input() -> None:
    vol = _blob()
    with pytest.raises(ValueError, match="cameras"):
        lg.bake_volume(vol, tf=TF, cameras=13, progress=False)
    with pytest.raises(ValueError, match="resolution"):
        lg.bake_volume(vol, tf=TF, resolution=0, progress=False)
    with pytest.raises(ValueError, match="scalar transfer function"):
        lg.bake_volume(vol, tf={"labels": {"1": [1, 0, 0, 1]}}, progress=False)
    with pytest.raises(ValueError, match="depth threshold"):
        lg.bake_volume(vol, tf=TF, depth_threshold=0.0, progress=False)
    with pytest.raises(TypeError, match="progress"):
        lg.bake_volume(vol, tf=TF, progress=3)  # type: ignore[arg-type]
    with pytest.raises(FileNotFoundError):
        lg.bake_volume("/nonexistent/head.nii.gz", tf="mri-brain", progress=False)


def _compression(lf: lg.LightField) -> dict[str, str | None]:
    return {c["name"]: c.get("compression") for c in lf.info["channels"]}


def test_block_compressed_volume_bakes_render_close_to_raw() -> None:
    """``color_codec="bc7"`` keeps the premultiplied colour with its alpha, ``depth_codec="bc4"``
    the 8-bit depth; the compressed bake's frame over black stays within 3 dB of the raw bake's
    PSNR against the direct ray cast (measured 23.95 against 23.98 dB here; the Rust suite
    measures 1.3 dB masked on a 96-px blob, where more of the frame is rim), and ``"bc1"``
    (1-bit alpha) is refused for semi-transparent colour."""
    vol = _blob()
    tf = {"points": [[0.0, 0, 0, 0, 0], [0.1, 0.2, 0.5, 0.9, 0.05], [0.5, 1, 0.8, 0.4, 0.8]]}
    common = {"tf": tf, "spacing": (0.8, 1.0, 1.2), "cameras": 42, "resolution": 64, "progress": False}
    raw = lg.bake_volume(vol, **common)  # type: ignore[arg-type]
    packed = lg.bake_volume(vol, color_codec="bc7", depth_codec="bc4", **common)  # type: ignore[arg-type]
    assert _compression(raw) == {"color": None, "depth": None}
    assert _compression(packed) == {"color": "bc7", "depth": "bc4"}
    view = {"eye": [30.0, 14.0, -20.0], "target": [6.0, 8.5, 11.4], "up": [0, 1, 0], "yfov_deg": 40, "width": 64, "height": 64}
    truth = _over_black(lg.reference_volume(vol, view, tf=tf, spacing=(0.8, 1.0, 1.2)).color)

    def psnr(lf: lg.LightField) -> float:
        mse = ((_over_black(lf.render(view).color) - truth) ** 2).mean()
        return float(10 * np.log10(255.0**2 / mse))

    raw_db, packed_db = psnr(raw), psnr(packed)
    assert packed_db > raw_db - 3.0, f"bc7 + bc4 {packed_db:.2f} dB against raw {raw_db:.2f} dB"
    with pytest.raises(ValueError, match="premultiplied"):
        lg.bake_volume(vol, color_codec="bc1", **common)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown block codec"):
        lg.bake_volume(vol, color_codec="dxt1", **common)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="use r16, r8 or bc4"):
        lg.bake_volume(vol, depth_codec="latc1", **common)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="do not pass depth_bits"):
        lg.bake_volume(vol, depth_codec="bc4", depth_bits=16, **common)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="multiple of 4"):
        lg.bake_volume(vol, tf=tf, cameras=12, resolution=30, color_codec="bc7", progress=False)


def test_layered_bake_renders_runtime_opacities_like_the_layered_reference() -> None:
    """A two-layer multi light field (the blob's faint outside and its dense inside through
    separate TFs): ``render(view, layers=...)`` against ``reference_volume(layers=...,
    opacities=...)`` with the same opacities, over black. The Rust suite measures the layered
    error (about that of one layer); here the fronts agree end to end: hiding the inside
    removes most of the opacity, and both sides agree within the one-layer test's bound."""
    vol = _blob()
    layers = [
        {"name": "outside", "tf": {"points": [[0.0, 0, 0, 0, 0], [0.1, 0.2, 0.5, 0.9, 0.05], [0.3, 0.2, 0.5, 0.9, 0.05], [0.31, 0, 0, 0, 0]]}, "opacity": 0.7},
        {"name": "inside", "tf": {"points": [[0.0, 0, 0, 0, 0], [0.3, 0, 0, 0, 0], [0.5, 1, 0.8, 0.4, 0.8]]}},
    ]
    lf = lg.bake_volume(vol, layers=layers, spacing=(0.8, 1.0, 1.2), cameras=42, resolution=64, progress=False)
    assert [layer["name"] for layer in lf.info["layers"]] == ["outside", "inside"]
    view = {"eye": [30.0, 14.0, -20.0], "target": [6.0, 8.5, 11.4], "up": [0, 1, 0], "yfov_deg": 40, "width": 64, "height": 64}

    alphas = []
    for opacities in ({}, {"inside": 0.0}, {"outside": 1.0, "inside": 0.4}):
        frame = lf.render(view, layers=opacities) if opacities else lf.render(view)
        truth = lg.reference_volume(vol, view, layers=layers, opacities=opacities, spacing=(0.8, 1.0, 1.2))
        a, b = _over_black(frame.color), _over_black(truth.color)
        psnr = 10 * np.log10(255.0**2 / max(((a - b) ** 2).mean(), 1e-12))
        assert psnr > 26.0, f"{opacities}: PSNR over black {psnr:.2f} dB"
        alphas.append(frame.color[..., 3].astype(float).mean())
    assert alphas[1] < 0.7 * alphas[0], f"hiding the inside removes opacity: {alphas}"
    # The string form works too; unknown layers and bad values are refused.
    same = lf.render(view, layers="inside=0")
    assert np.array_equal(same.color, lf.render(view, layers={"inside": 0.0}).color)
    with pytest.raises(ValueError, match="no layer"):
        lf.render(view, layers={"skin": 1.0})
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        lf.render(view, layers={"inside": 2.0})
    with pytest.raises(ValueError, match="not both"):
        lg.bake_volume(vol, tf=TF, layers=layers, progress=False)
    with pytest.raises(ValueError, match="tf .* or layers"):
        lg.bake_volume(vol, progress=False)
    with pytest.raises(ValueError, match="used twice"):
        lg.bake_volume(vol, layers=[layers[0], layers[0]], progress=False)


def test_depth_layers_split_each_ray_and_add_up_to_the_whole_ray_cast() -> None:
    """Depth layers (seed 002 §7) from a dict: the blob's rays cut where their opacity reaches
    0.35. At full opacity the segments' composited ray casts are the one-layer ray cast (each
    segment is quantized to 8-bit premultiplied codes first, so over black within 2 levels);
    the baked layers render like that reference (PSNR over black, the bound of the two-layer
    test above); fading the back segment leaves the front one's opacity."""
    vol = _blob()
    split = {"tf": TF, "split": {"opacity": [0.35]}, "layers": [{"name": "front"}, {"name": "back", "opacity": 0.5}]}
    lf = lg.bake_volume(vol, layers=split, spacing=(0.8, 1.0, 1.2), cameras=42, resolution=64, progress=False)
    assert lf.info["format_version"] == 3 and lf.info["layer_order"] == "ray"
    assert [layer["name"] for layer in lf.info["layers"]] == ["front", "back"]
    view = {"eye": [30.0, 14.0, -20.0], "target": [6.0, 8.5, 11.4], "up": [0, 1, 0], "yfov_deg": 40, "width": 64, "height": 64}

    whole = lg.reference_volume(vol, view, tf=TF, spacing=(0.8, 1.0, 1.2))
    segments = lg.reference_volume(vol, view, layers=split, opacities={"back": 1.0}, spacing=(0.8, 1.0, 1.2))
    assert np.abs(_over_black(whole.color) - _over_black(segments.color)).max() <= 2.0
    assert np.abs(whole.color[..., 3].astype(int) - segments.color[..., 3].astype(int)).max() <= 2
    for opacities in ({"back": 1.0}, {}, {"back": 0.0}):
        frame = lf.render(view, layers=opacities)
        truth = lg.reference_volume(vol, view, layers=split, opacities=opacities, spacing=(0.8, 1.0, 1.2))
        a, b = _over_black(frame.color), _over_black(truth.color)
        psnr = 10 * np.log10(255.0**2 / max(((a - b) ** 2).mean(), 1e-12))
        assert psnr > 26.0, f"{opacities}: PSNR over black {psnr:.2f} dB"
    front = lf.render(view, layers={"back": 0.0}).color[..., 3].astype(float)
    full = lf.render(view, layers={"back": 1.0}).color[..., 3].astype(float)
    assert 0 < front.mean() < 0.8 * full.mean(), f"the front segment alone: {front.mean():.1f} of {full.mean():.1f}"
    with pytest.raises(ValueError, match="depth layers"):
        lg.bake_volume(vol, layers={**split, "layers": [{"name": "front"}]}, progress=False)
