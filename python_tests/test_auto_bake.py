"""`bake_mesh(auto=True)`: the automatic bake's flags and errors, and its report on a target
outside what any setting reaches."""

from __future__ import annotations

import math

import pytest

import lumigraph as lg


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"target_psnr": math.nan}, "target PSNR"),
        ({"target_psnr": math.inf}, "target PSNR"),
        ({"target_psnr": -3.0}, "target PSNR"),
        ({"target_psnr": 0.0}, "target PSNR"),
        ({"target_psnr": 150.0}, "target PSNR"),
        ({"max_bytes": 0}, "max bytes"),
        ({"target_psnr": 27.0, "max_bytes": 100_000}, "not both"),
        ({"cameras": 42}, "chooses cameras"),
        ({"resolution": 128, "depth_bits": 8}, "chooses resolution, depth_bits"),
    ],
)
def test_bad_targets_and_flags_are_refused(
    demo_mesh: lg.Mesh, kwargs: dict[str, object], match: str
) -> None:
    with pytest.raises(ValueError, match=match):
        lg.bake_mesh(demo_mesh, auto=True, progress=False, **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("kwargs", [{"target_psnr": 27.0}, {"max_bytes": 100_000}])
def test_targets_without_auto_are_refused(demo_mesh: lg.Mesh, kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="auto=True"):
        lg.bake_mesh(demo_mesh, progress=False, **kwargs)  # type: ignore[arg-type]


def test_a_budget_below_every_setting_bakes_the_smallest_and_flags_it(demo_mesh: lg.Mesh) -> None:
    lf = lg.bake_mesh(demo_mesh, auto=True, max_bytes=1, progress=False)
    report = lf.info["quality"]["auto_bake"]
    assert report["target"] == {"max_bytes": 1}
    assert report["choice"]["reach"] == "budget_too_small"
    assert report["target_met"] is False
    assert "max bytes 1 is below the smallest setting" in report["message"]
    setting = report["choice"]["setting"]
    # The smallest setting of the grid, and the asset holds exactly it.
    assert (setting["cameras"], setting["resolution"]) == (12, 64)
    assert (lf.cameras, lf.resolution) == (12, 64)
    assert math.isfinite(report["measured_psnr"]) and report["measured_psnr"] > 10
    assert report["held_out_views"] == 24
