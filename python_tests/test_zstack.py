"""z-stacks from Python (docs/zstack.md): `lg.import_zstack` takes a numpy stack or a path and
gives a two-plane light field that renders (resident or through the paged cache) with the stack's
bright bead where a view from above sees it; bad stacks and options raise clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lumigraph as lg


def _stack() -> np.ndarray:
    """6 slices of 40 x 32, a dim background and one bright bead at slice 4, row 10, column 25."""
    stack = np.full((6, 32, 40), 1000, dtype=np.uint16)
    stack[4, 10, 25] = 60000
    return stack


def _top_view(lf: lg.LightField, size: int = 64) -> dict[str, object]:
    planes = lf.planes
    assert planes is not None
    h = planes["uv"]["center"][2]
    return {
        "eye": [0, 0, 1.5 * h],
        "target": [0, 0, 0],
        "up": [0, 1, 0],
        "yfov_deg": 12,
        "width": size,
        "height": size,
    }


def test_import_zstack_from_an_array_renders_the_bead(tmp_path: Path) -> None:
    lf = lg.import_zstack(_stack(), spacing=(0.5, 0.5, 2.0), grid=(5, 5), window=(0, 60000))
    assert lf.kind == "two_plane"
    planes = lf.planes
    assert planes is not None
    assert planes["st"]["resolution"] == [40, 32]
    assert planes["st"]["size"] == [20.0, 16.0]
    assert planes["uv"]["grid"] == [5, 5]
    frame = lf.render(_top_view(lf), background=(0, 0, 0))
    grey = frame.color[..., 0].astype(int)
    # The bead is the brightest spot, right of the centre and above it (row 10 of 32, column 25
    # of 40: +x and +y of the st centre), seen from above the stack's centre.
    # A single voxel, blended between cameras: far brighter than the background (code 4).
    row, col = np.unravel_index(np.argmax(grey), grey.shape)
    assert grey[row, col] > 40 and grey[row, col] > 5 * np.median(grey)
    assert col > 32 and row < 32
    # To a file, then through a paged cache: the same frame where nothing is degraded.
    path = tmp_path / "stack.lfa"
    saved = lg.import_zstack(_stack(), spacing=(0.5, 0.5, 2.0), grid=(5, 5), window=(0, 60000), output=path)
    assert path.is_file() and saved.kind == "two_plane"
    paged = lg.LightField.open(path, cache_mib=64)
    again = paged.render(_top_view(lf), background=(0, 0, 0))
    stats = paged.page_stats
    assert stats is not None and stats["last"]["degraded_px"] == 0
    assert np.abs(again.color.astype(int) - frame.color.astype(int)).max() <= 2


def test_import_zstack_errors_are_clear(tmp_path: Path) -> None:
    with pytest.raises(TypeError, match="uint8 or uint16"):
        lg.import_zstack(np.zeros((2, 4, 4), dtype=np.float32))
    with pytest.raises(ValueError, match="3-D array"):
        lg.import_zstack(np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(ValueError, match="empty stack"):
        lg.import_zstack(np.zeros((0, 4, 4), dtype=np.uint8))
    with pytest.raises(ValueError, match="mip or over"):
        lg.import_zstack(_stack(), composite="sum")
    with pytest.raises(ValueError, match="grid"):
        lg.import_zstack(_stack(), grid=(0, 3))
    with pytest.raises(ValueError, match="window"):
        lg.import_zstack(_stack(), window=(5, 5))
    with pytest.raises(FileNotFoundError):
        lg.import_zstack(tmp_path / "missing.tif")
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"II*\x00garbage")
    with pytest.raises(ValueError, match="bad.tif"):
        lg.import_zstack(bad)
