"""lumigraph.metrics (the core's one implementation) against scikit-image and numpy.

Tolerance 1e-6 (absolute, dB for PSNR): the core computes PSNR from an exact integer sum of
squares and SSIM from exact integer window sums, so the only differences to scikit-image's float64
arithmetic are rounding (~1e-13); 1e-6 is the issue's bound with a wide margin.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

import lumigraph as lg

TOL = 1e-6


def sk_psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(peak_signal_noise_ratio(a[..., :3], b[..., :3], data_range=255))


def sk_ssim(a: np.ndarray, b: np.ndarray) -> float:
    return float(structural_similarity(a[..., :3], b[..., :3], channel_axis=-1, data_range=255))


def noisy_pair(rng: np.random.Generator, h: int, w: int, noise: int) -> tuple[np.ndarray, np.ndarray]:
    a = rng.integers(0, 256, size=(h, w, 4), dtype=np.uint8)
    delta = rng.integers(-noise, noise + 1, size=(h, w, 4))
    b = np.clip(a.astype(int) + delta, 0, 255).astype(np.uint8)
    b[0, 0, 0] = a[0, 0, 0] ^ 1  # never identical
    return a, b


@pytest.mark.parametrize(("h", "w", "noise"), [(7, 7, 255), (37, 53, 20), (96, 128, 3), (128, 64, 60)])
def test_psnr_ssim_mae_equal_scikit_image_on_random_images(h: int, w: int, noise: int) -> None:
    rng = np.random.default_rng(h * 1000 + w)
    a, b = noisy_pair(rng, h, w, noise)
    assert lg.metrics.psnr(a, b) == pytest.approx(sk_psnr(a, b), abs=TOL)
    assert lg.metrics.ssim(a, b) == pytest.approx(sk_ssim(a, b), abs=TOL)
    mae = np.abs(a[..., :3].astype(float) - b[..., :3].astype(float)).mean()
    assert lg.metrics.mae(a, b) == pytest.approx(mae, abs=TOL)
    # RGB input is the same as RGBA (alpha is ignored).
    assert lg.metrics.psnr(a[..., :3], b[..., :3]) == lg.metrics.psnr(a, b)
    assert lg.metrics.ssim(a[..., :3], b) == lg.metrics.ssim(a, b)


def test_masked_psnr_equals_scikit_image_on_the_union_of_masks() -> None:
    rng = np.random.default_rng(7)
    a, b = noisy_pair(rng, 64, 80, 40)
    ca = rng.random((64, 80)) < 0.4
    cb = rng.random((64, 80)) < 0.4
    union = ca | cb
    ours = lg.metrics.masked_psnr(a, b, test_coverage=ca, reference_coverage=cb)
    theirs = float(peak_signal_noise_ratio(a[union][:, :3], b[union][:, :3], data_range=255))
    assert ours == pytest.approx(theirs, abs=TOL)
    assert lg.metrics.psnr(a, b, mask=union) == ours


def test_metrics_equal_scikit_image_on_real_frames(
    demo_mesh: lg.Mesh, demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    for view in demo_views:
        test = demo_lf.render(view)
        ref = lg.reference_render(demo_mesh, view, **demo_lf.shading)
        a, b = test.color, ref.color
        assert lg.metrics.psnr(test, ref) == pytest.approx(sk_psnr(a, b), abs=TOL)
        assert lg.metrics.ssim(test, ref) == pytest.approx(sk_ssim(a, b), abs=TOL)
        union = test.coverage | ref.coverage
        masked = float(peak_signal_noise_ratio(a[union][:, :3], b[union][:, :3], data_range=255))
        assert lg.metrics.masked_psnr(test, ref) == pytest.approx(masked, abs=TOL)
        both = test.coverage & ref.coverage
        err = np.abs(test.depth[both].astype(np.float64) - ref.depth[both].astype(np.float64))
        stats = lg.metrics.depth_error(test, ref)
        assert stats["count"] == both.sum()
        assert stats["median"] == pytest.approx(np.median(err), abs=1e-12)
        assert stats["mean"] == pytest.approx(err.mean(), rel=1e-12)
        assert stats["max"] == pytest.approx(err.max(), abs=1e-12)
        assert stats["p95"] == pytest.approx(np.percentile(err, 95), abs=1e-12)
        full = lg.metrics.compare(test, ref)
        assert full["masked_psnr"] == pytest.approx(masked, abs=TOL)
        assert full["union_px"] == union.sum()
        assert full["mask_mismatch_px"] == (test.coverage ^ ref.coverage).sum()
        # Arrays and frames give the same numbers.
        assert lg.metrics.depth_error(test.depth, ref.depth) == stats


def test_identical_images_give_infinite_psnr_and_ssim_one() -> None:
    a = np.full((16, 16, 4), 100, dtype=np.uint8)
    assert lg.metrics.psnr(a, a) == float("inf")
    assert lg.metrics.ssim(a, a) == pytest.approx(1.0)
    assert lg.metrics.mae(a, a) == 0.0
    empty = lg.metrics.depth_error(np.full((4, 4), np.inf, np.float32), np.ones((4, 4), np.float32))
    assert empty["count"] == 0 and np.isnan(empty["median"])


images = st.integers(8, 24).flatmap(
    lambda h: st.integers(8, 24).flatmap(
        lambda w: st.tuples(
            arrays(np.uint8, (h, w, 3)), arrays(np.uint8, (h, w, 3))
        )
    )
)


@settings(max_examples=40, deadline=None)
@given(images)
def test_property_metrics_match_scikit_image_and_are_symmetric(pair: tuple[np.ndarray, np.ndarray]) -> None:
    a, b = pair
    ours = lg.metrics.psnr(a, b)
    assert ours == lg.metrics.psnr(b, a)
    assert lg.metrics.ssim(a, b) == pytest.approx(lg.metrics.ssim(b, a), abs=1e-12)
    if np.array_equal(a, b):
        assert ours == float("inf")
    else:
        assert ours == pytest.approx(sk_psnr(a, b), abs=TOL)
    assert lg.metrics.ssim(a, b) == pytest.approx(sk_ssim(a, b), abs=TOL)
