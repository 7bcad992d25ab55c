"""A frame's colour and depth through OpenEXR (the ``OpenEXR`` package) and back: float32 depth,
+inf included, round-trips bit-exactly; colour as float32 in [0, 1] returns the same 8-bit values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lumigraph as lg

OpenEXR = pytest.importorskip("OpenEXR")


def test_depth_round_trips_bit_exactly(
    demo_lf: lg.LightField, demo_views: list[lg.View], tmp_path: Path
) -> None:
    frame = demo_lf.render(demo_views[2])
    depth = frame.depth
    rgba = frame.color.astype(np.float32) / 255.0
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {"RGBA": rgba, "Z": depth}
    path = tmp_path / "frame.exr"
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))
    with OpenEXR.File(str(path)) as f:
        back_z = f.channels()["Z"].pixels
        back_rgba = f.channels()["RGBA"].pixels
    assert back_z.dtype == np.float32 and back_z.shape == depth.shape
    np.testing.assert_array_equal(back_z.view(np.uint32), depth.view(np.uint32))
    assert np.isinf(back_z).sum() == (~frame.coverage).sum() > 0
    np.testing.assert_array_equal(np.round(back_rgba * 255).astype(np.uint8), frame.color)
