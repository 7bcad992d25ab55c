"""The Python API of the bindings: bake, open/save/info, render, render_many, views, frames,
reference renders, threads and the GIL, docstrings, the README quick start."""

from __future__ import annotations

import json
import runpy
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import lumigraph as lg

from bindings_helpers import ROOT, icosphere_arrays


def test_frame_arrays_have_the_documented_dtypes_and_shapes(
    demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    frame = demo_lf.render(demo_views[0])
    assert frame.color.shape == (96, 96, 4) and frame.color.dtype == np.uint8
    assert frame.depth.shape == (96, 96) and frame.depth.dtype == np.float32
    assert frame.coverage.shape == (96, 96) and frame.coverage.dtype == np.bool_
    assert frame.color.flags.c_contiguous and frame.depth.flags.c_contiguous
    np.testing.assert_array_equal(frame.coverage, np.isfinite(frame.depth))
    assert 0 < frame.covered_px == int(frame.coverage.sum()) < 96 * 96
    assert np.all(frame.depth[frame.coverage] > 0)
    # Outside coverage: transparent black by default (DESIGN §3).
    assert not frame.color[~frame.coverage].any()
    assert set(frame.stats) == {"render_ms", "rays", "steps", "fetches"}
    assert frame.stats["render_ms"] > 0 and frame.stats["rays"] > 0
    # Arrays are copies: modifying one does not change the frame.
    frame.color[:] = 7
    assert not frame.color[~frame.coverage].any()


def test_views_as_dicts_and_view_objects_render_the_same(
    demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    view = demo_views[1]
    as_dict = view.to_dict()
    a = demo_lf.render(view)
    b = demo_lf.render(as_dict)
    c = demo_lf.render(lg.View.from_json(json.dumps(as_dict)))
    np.testing.assert_array_equal(a.color, b.color)
    np.testing.assert_array_equal(a.depth, c.depth)


def test_render_many_equals_render(demo_lf: lg.LightField, demo_views: list[lg.View]) -> None:
    frames = demo_lf.render_many(demo_views, step=1 / 48)
    assert len(frames) == len(demo_views)
    for view, frame in zip(demo_views, frames, strict=True):
        single = demo_lf.render(view, step=1 / 48)
        np.testing.assert_array_equal(frame.color, single.color)
        np.testing.assert_array_equal(frame.depth, single.depth)
    assert demo_lf.render_many([]) == []


def test_background_fills_uncovered_pixels(
    demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    plain = demo_lf.render(demo_views[0])
    white = demo_lf.render(demo_views[0], background=(255, 255, 255))
    assert np.all(white.color[~white.coverage] == 255)
    np.testing.assert_array_equal(white.color[white.coverage], plain.color[plain.coverage])
    rgba = demo_lf.render(demo_views[0], background=[10, 20, 30, 40])
    assert np.all(rgba.color[~rgba.coverage] == [10, 20, 30, 40])


def test_quality_knobs_change_the_work_done(
    demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    coarse = demo_lf.render(demo_views[0], method="fixed", step=1 / 16)
    fine = demo_lf.render(demo_views[0], method="fixed", step=1 / 128)
    assert fine.stats["steps"] > 2 * coarse.stats["steps"]
    lod12 = demo_lf.render(demo_views[0], lod=12)
    assert lod12.covered_px > 0
    # Tolerance below step/2 leaves gaps (seed 000 §3.1): coverage drops.
    gappy = demo_lf.render(demo_views[0], method="fixed", step=1 / 16, tolerance=1 / 400)
    assert gappy.covered_px < coarse.covered_px


def test_save_open_info_round_trip(demo_lf: lg.LightField, tmp_path: Path) -> None:
    path = tmp_path / "demo.lfa"
    demo_lf.save(path)
    assert not list(tmp_path.glob(".*tmp*")), "atomic save leaves no temporary file"
    opened = lg.LightField.open(path)
    assert opened.info == demo_lf.info
    assert opened.to_bytes() == demo_lf.to_bytes() == path.read_bytes()
    opened.verify()
    info = opened.info
    assert info["kind"] == "spherical"
    assert info["geometry"]["camera_count"] == opened.cameras == 42
    assert info["geometry"]["resolution_px"] == opened.resolution == 96
    assert info["provenance"]["source_name"] == "demo:trefoil"
    assert info["provenance"]["bake_options"]["cameras"] == 42
    assert opened.bounding_sphere[1] == pytest.approx(info["frame"]["radius"])
    # Saving an opened asset copies it (re-validated), and str paths work too.
    opened.save(str(tmp_path / "copy.lfa"))
    assert (tmp_path / "copy.lfa").read_bytes() == path.read_bytes()


def test_bake_inputs_arrays_tuples_paths_and_meshes_agree(tmp_path: Path) -> None:
    vertices, faces = icosphere_arrays(2)
    colors = np.tile(np.array([[200, 50, 50, 255]], dtype=np.uint8), (len(vertices), 1))
    kwargs = {"cameras": 12, "resolution": 32, "progress": False}
    from_tuple = lg.bake_mesh((vertices, faces, colors), **kwargs)
    from_mesh = lg.bake_mesh(lg.Mesh(vertices, faces, colors), **kwargs)
    # float colours in [0, 1] mean the same as uint8 / 255
    from_float = lg.bake_mesh((vertices, faces, colors / 255.0), **kwargs)
    view = {"eye": [0, 0, 3], "target": [0, 0, 0], "yfov_deg": 45, "width": 48, "height": 48}
    a, b, c = (lf.render(view) for lf in (from_tuple, from_mesh, from_float))
    np.testing.assert_array_equal(a.color, b.color)
    np.testing.assert_array_equal(a.color, c.color)
    # The colour is honoured: red dominates where covered.
    px = a.color[a.coverage].astype(int)
    assert (px[:, 0] > 2 * px[:, 1] + 10).mean() > 0.95
    # A path goes through lumigraph's loaders.
    obj = tmp_path / "sphere.obj"
    obj.write_text(
        "".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
        + "".join(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in faces)
    )
    from_path = lg.bake_mesh(obj, **kwargs)
    assert from_path.info["provenance"]["source_name"] == "sphere.obj"
    grey = from_path.render(view)
    np.testing.assert_array_equal(grey.coverage, a.coverage)


def test_progress_callback_and_printer(demo_mesh: lg.Mesh, capsys: pytest.CaptureFixture[str]) -> None:
    calls: list[tuple[int, int]] = []
    lg.bake_mesh(demo_mesh, cameras=12, resolution=16, progress=lambda d, t: calls.append((d, t)))
    assert calls and calls[-1] == (12, 12)
    assert all(t == 12 for _, t in calls)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)
    lg.bake_mesh(demo_mesh, cameras=12, resolution=16)
    assert "baking cameras 12/12" in capsys.readouterr().err


def test_progress_callback_exception_is_raised_after_the_bake(demo_mesh: lg.Mesh) -> None:
    def fail(done: int, total: int) -> None:
        raise KeyError("stop")

    with pytest.raises(KeyError, match="stop"):
        lg.bake_mesh(demo_mesh, cameras=12, resolution=16, progress=fail)


def test_reference_render_matches_its_light_field(
    demo_mesh: lg.Mesh, demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    for view in demo_views[:2]:
        ref = lg.reference_render(demo_mesh, view, **demo_lf.shading)
        frame = demo_lf.render(view)
        # A loose sanity floor; the calibrated floors are in test_quality.py.
        assert lg.metrics.masked_psnr(frame, ref) > 18.0
        assert lg.metrics.compare(frame, ref)["mask_mismatch_px"] < 0.1 * ref.covered_px


def test_block_compressed_bakes_record_their_codecs_and_render(
    demo_mesh: lg.Mesh, demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    """``color_codec`` / ``depth_codec`` as ``bake --color-codec`` / ``--depth-codec``: the
    asset records them and scores within 6 dB of the raw bake's masked PSNR on the demo
    (measured 2.7 and 4.7 dB lower on the two views at 42 cameras × 96 px; the codecs drop the edge texels and BC4 blurs depth across silhouettes,
    BENCHMARKS "Block compression"). Bad names and combinations are ValueErrors."""
    packed = lg.bake_mesh(demo_mesh, cameras=42, resolution=96, color_codec="bc1", depth_codec="bc4", progress=False)
    assert {c["name"]: c.get("compression") for c in packed.info["channels"]} == {"color": "bc1", "depth": "bc4"}
    r8 = lg.bake_mesh(demo_mesh, cameras=42, resolution=96, depth_codec="r8", progress=False)
    assert {c["name"]: c["encoding"] for c in r8.info["channels"]}["depth"] == "r8"
    for view in demo_views[:2]:
        ref = lg.reference_render(demo_mesh, view, **demo_lf.shading)
        raw_db = lg.metrics.masked_psnr(demo_lf.render(view), ref)
        packed_db = lg.metrics.masked_psnr(packed.render(view), ref)
        assert packed_db > raw_db - 6.0, f"bc1 + bc4 {packed_db:.2f} dB against raw {raw_db:.2f} dB"
    for kwargs, match in [
        ({"cameras": 12, "color_codec": "bc4"}, "colour codec bc4: use bc1 or bc7"),
        ({"cameras": 12, "depth_codec": "bc7"}, "use r16, r8 or bc4"),
        ({"cameras": 12, "depth_codec": "r8", "depth_bits": 16}, "do not pass depth_bits"),
        ({"auto": True, "color_codec": "bc1"}, "auto=True bakes raw pages"),
        ({"cameras": 12, "color_codec": "bc1", "resolution": 30}, "multiple of 4"),
    ]:
        with pytest.raises(ValueError, match=match):
            lg.bake_mesh(demo_mesh, progress=False, **kwargs)  # type: ignore[arg-type]


def test_shading_options_change_the_reference(demo_mesh: lg.Mesh, demo_views: list[lg.View]) -> None:
    view = demo_views[0]
    lit = lg.reference_render(demo_mesh, view)
    unlit = lg.reference_render(demo_mesh, view, unlit=True)
    spec = lg.reference_render(demo_mesh, view, specular=(0.5, 20.0))
    dark = lg.reference_render(demo_mesh, view, ambient=0.0)
    cov = lit.coverage
    mean = lambda f: f.color[cov][:, :3].astype(float).mean()  # noqa: E731
    assert mean(unlit) > mean(lit)  # ambient + diffuse <= 1 darkens the albedo
    assert mean(spec) > mean(lit)
    assert mean(dark) < mean(lit)
    np.testing.assert_array_equal(lit.depth, unlit.depth)


def test_shadows_reach_the_bake_and_the_reference(demo_mesh: lg.Mesh, demo_views: list[lg.View]) -> None:
    lf = lg.bake_mesh(demo_mesh, cameras=42, resolution=96, shadows=True, progress=False)
    assert lf.shading["shadows"] is True
    view = demo_views[1]
    lit = lg.reference_render(demo_mesh, view)
    shadowed = lg.reference_render(demo_mesh, view, **lf.shading)
    cov = lit.coverage
    np.testing.assert_array_equal(cov, shadowed.coverage)
    # Shadows only take light away (one code of rounding), and the trefoil shadows itself.
    a = lit.color[cov][:, :3].astype(int)
    b = shadowed.color[cov][:, :3].astype(int)
    assert (b <= a + 1).all()
    assert ((a - b).max(axis=1) > 20).mean() > 0.02
    # The light field carries the baked shadows: closer to the shadowed reference than to the
    # lit one.
    frame = lf.render(view)
    assert lg.metrics.masked_psnr(frame, shadowed) > lg.metrics.masked_psnr(frame, lit) + 1.0


def _yard(box_x: float) -> tuple[np.ndarray, np.ndarray]:
    """A ground quad (±2) with a 0.5 box standing on it at x in [box_x, box_x + 0.5]."""
    ground = np.array([[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]], dtype=np.float32)
    lo, hi = np.array([box_x, 0.0, -0.25]), np.array([box_x + 0.5, 0.5, 0.25])
    corners = np.array(
        [[(hi if i & (1 << a) else lo)[a] for a in range(3)] for i in range(8)], dtype=np.float32
    )
    faces = [[0, 1, 2], [0, 2, 3]]
    for f in ([0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]):
        g = [4 + i for i in f]
        faces += [[g[0], g[1], g[2]], [g[0], g[2], g[3]]]
    return np.vstack([ground, corners]), np.array(faces, dtype=np.uint32)


def test_deformation_states_store_what_changed_and_render_by_name() -> None:
    base, moved = _yard(-0.8), _yard(0.6)
    lf = lg.bake_mesh(
        base, cameras=42, resolution=128, shadows=True, states={"moved": moved, "same": base},
        progress=False,
    )
    assert lf.info["format_version"] == 4
    by_name = {d["name"]: d for d in lf.deformations}
    assert set(by_name) == {"moved", "same"}
    assert by_name["same"]["stored_pages"] == 0  # a deterministic bake: nothing differs
    assert 0.0 < by_name["moved"]["fraction"] < 0.5
    view = lg.View(eye=(0.0, 4.0, 4.5), target=(0.0, 0.2, 0.0), yfov_deg=40.0, width=128, height=128)
    frame = lf.render(view, state="moved")
    truth = lg.reference_render(moved, view, **lf.shading)
    truth_base = lg.reference_render(base, view, **lf.shading)
    plain = lf.render(view)
    # Each state is closer to its own mesh's reference (the box is a small part of the view).
    assert lg.metrics.masked_psnr(frame, truth) > lg.metrics.masked_psnr(plain, truth) + 1.0
    assert lg.metrics.masked_psnr(plain, truth_base) > lg.metrics.masked_psnr(frame, truth_base) + 1.0
    np.testing.assert_array_equal(lf.render(view, state="base").color, lf.render(view).color)
    with pytest.raises(ValueError, match="unknown state"):
        lf.render(view, state="dent")
    # Animation frames are picked by time or frame, of assets baked with --animation only.
    with pytest.raises(ValueError, match="no animation"):
        lf.render(view, time=0.0)
    with pytest.raises(ValueError, match="one of time, frame and state"):
        lf.render(view, frame=0, state="moved")
    with pytest.raises(ValueError, match="bounding sphere"):
        lg.bake_mesh(base, cameras=12, resolution=16, states={"big": (base[0] * 3.0, base[1])}, progress=False)
    with pytest.raises(ValueError, match="base"):
        lg.bake_mesh(base, cameras=12, resolution=16, states={"base": base}, progress=False)
    with pytest.raises(ValueError, match="lights"):
        lg.bake_mesh(base, cameras=12, resolution=16, lights=12, states={"s": base}, progress=False)


def test_bake_animation_renders_frames_by_time_and_frame() -> None:
    from bindings_helpers import fixtures_dir

    cube = fixtures_dir() / "anim" / "AnimatedMorphCube.gltf"
    lf = lg.bake_animation(cube, fps=4, cameras=12, resolution=48, progress=False)
    base = lf.info["states"][0]["params"]["animation"]
    assert base["name"] == "Square" and base["fps"] == 4.0
    frames = len(lf.info["states"])
    assert frames > 10
    view = lg.View(eye=(0.1, 0.05, 0.12), target=(0, 0, 0), yfov_deg=40.0, width=48, height=48)
    np.testing.assert_array_equal(lf.render(view, time=1.3).color, lf.render(view, frame=5).color)
    assert not np.array_equal(lf.render(view, frame=0).color, lf.render(view, frame=8).color)
    with pytest.raises(ValueError, match="outside the animation"):
        lf.render(view, time=99.0)
    with pytest.raises(lg.MeshError, match="no animation \"Walk\""):
        lg.bake_animation(cube, animation="Walk", progress=False)
    with pytest.raises(lg.MeshError, match="fps"):
        lg.bake_animation(cube, fps=0.0, progress=False)


def test_light_states_relight_at_any_direction(
    demo_mesh: lg.Mesh, demo_views: list[lg.View]
) -> None:
    lf = lg.bake_mesh(demo_mesh, cameras=42, resolution=96, shadows=True, lights=12, progress=False)
    view = demo_views[1]
    # At a light between the proxy's directions the relit frame follows the reference with that
    # light: closer to it than to the reference with the bake's own light.
    light = (0.6, 0.3, -0.75)
    relit = lf.render(view, light=light)
    truth = lg.reference_render(demo_mesh, view, **{**lf.shading, "light": light})
    baked = lg.reference_render(demo_mesh, view, **lf.shading)
    np.testing.assert_array_equal(relit.coverage, lf.render(view).coverage)
    assert lg.metrics.masked_psnr(relit, truth) > lg.metrics.masked_psnr(relit, baked) + 3.0
    # Within a few dB of a bake with exactly that light (12 light directions 63° apart blend
    # three shadows where the truth has one).
    exact = lg.bake_mesh(
        demo_mesh, cameras=42, resolution=96, shadows=True, light=light, progress=False
    ).render(view)
    assert lg.metrics.masked_psnr(relit, truth) > lg.metrics.masked_psnr(exact, truth) - 4.0
    for bad in [(0.0, 0.0, 0.0), (float("nan"), 1.0, 0.0)]:
        with pytest.raises(ValueError, match="light"):
            lf.render(view, light=bad)
    plain = lg.bake_mesh(demo_mesh, cameras=12, resolution=32, progress=False)
    with pytest.raises(ValueError, match="no light states"):
        plain.render(view, light=(0.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="12, 42 or 162"):
        lg.bake_mesh(demo_mesh, cameras=12, resolution=32, lights=7, progress=False)


def test_render_releases_the_gil_and_threads_agree(
    demo_lf: lg.LightField, demo_views: list[lg.View]
) -> None:
    views = demo_views * 2
    serial = [demo_lf.render(v).color for v in views]
    results: dict[int, np.ndarray] = {}
    ticks = 0
    stop = threading.Event()

    def ticker() -> None:
        nonlocal ticks
        while not stop.is_set():
            ticks += 1
            time.sleep(0.0005)

    def work(i: int) -> None:
        results[i] = demo_lf.render(views[i]).color

    tick_thread = threading.Thread(target=ticker)
    tick_thread.start()
    workers = [threading.Thread(target=work, args=(i,)) for i in range(len(views))]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    stop.set()
    tick_thread.join()
    for i, color in enumerate(serial):
        np.testing.assert_array_equal(results[i], color)
    # With the GIL held during renders the ticker would barely run.
    assert ticks > 20


def test_device_info_names_an_adapter() -> None:
    assert isinstance(lg.device_info(), str) and lg.device_info()


def test_public_api_has_docstrings_with_units() -> None:
    for obj in (lg.bake_mesh, lg.reference_render, lg.as_mesh, lg.LightField.render,
                lg.LightField.render_many, lg.LightField.open, lg.View, lg.Mesh, lg.Frame,
                lg.metrics.psnr, lg.metrics.masked_psnr, lg.metrics.ssim, lg.metrics.mae,
                lg.metrics.depth_error, lg.orbit_views):  # fmt: skip
        assert obj.__doc__ and len(obj.__doc__) > 60, obj
    assert "pixels" in (lg.bake_mesh.__doc__ or "")
    assert "diameters" in (lg.LightField.render.__doc__ or "")
    assert "world units" in (lg.Frame.__doc__ or "")
    text = lg.LightField.render.__text_signature__ or ""
    assert "*" in text and "**quality" in text
    for name in lg.__all__:
        assert hasattr(lg, name), name


def test_quickstart_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    runpy.run_path(str(ROOT / "pylib" / "examples" / "quickstart.py"), run_name="__main__")
    assert lg.LightField.open(tmp_path / "sphere.lfa").cameras == 42


def test_readme_quick_start_is_the_tested_example() -> None:
    """The README's Python quick start must be pylib/examples/quickstart.py, which runs above."""
    readme = (ROOT / "README.md").read_text()
    blocks = [b.split("\n", 1)[1] for b in readme.split("```python")[1:]]
    starts = [b.split("```", 1)[0] for b in blocks if "import lumigraph" in b]
    assert starts, "README.md has no Python quick start"
    example = (ROOT / "pylib" / "examples" / "quickstart.py").read_text()
    assert starts[0].strip() == example.strip(), "README quick start differs from pylib/examples/quickstart.py"


@pytest.fixture(scope="module")
def calibrated_lf(demo_mesh: lg.Mesh) -> lg.LightField:
    """The demo at 42 cameras, 64-px maps, calibrated (a few seconds)."""
    return lg.bake_mesh(demo_mesh, cameras=42, resolution=64, progress=False, calibrate=True)


def test_calibrated_goals_choose_settings_and_render_them(
    calibrated_lf: lg.LightField, demo_mesh: lg.Mesh, demo_views: list[lg.View]
) -> None:
    lf = calibrated_lf
    points = lf.info["quality"]["calibration"]["points"]
    # Every camera count the asset holds × 4 steps, each with a finite prediction.
    assert {(p["cameras"], p["step"]) for p in points} == {
        (c, s) for c in (12, 42) for s in (1 / 8, 1 / 16, 1 / 32, 1 / 64)
    }
    assert all(np.isfinite(p["ms_per_mpx"]) and p["masked_psnr"] > 10 for p in points)
    view = demo_views[0]
    best = max(p["masked_psnr"] for p in points)
    choice = lf.choose(view, target_psnr=best - 0.01)
    assert choice["met"] is True
    assert choice["predicted_psnr"] >= best - 0.01
    # The cheapest setting reaching the target, by the calibration's own numbers.
    mpx = view.width * view.height / 1e6
    cheapest = min(
        (p for p in points if p["masked_psnr"] >= best - 0.01), key=lambda p: p["ms_per_mpx"]
    )
    assert choice["cameras"] == cheapest["cameras"]
    assert choice["step"] == pytest.approx(cheapest["step"])
    assert choice["predicted_ms"] == pytest.approx(cheapest["ms_per_mpx"] * mpx)
    # render(target_psnr=...) renders exactly the chosen setting.
    chosen = lf.render(view, target_psnr=best - 0.01)
    explicit = lf.render(view, lod=choice["cameras"], step=choice["step"])
    np.testing.assert_array_equal(chosen.color, explicit.color)
    np.testing.assert_array_equal(chosen.depth, explicit.depth)
    # A budget: the most accurate setting predicted to fit; an impossible one is flagged.
    roomy = lf.choose(view, budget_ms=1e6)
    assert roomy["met"] is True and roomy["predicted_psnr"] == pytest.approx(best)
    tight = lf.choose(view, budget_ms=1e-6)
    assert tight["met"] is False
    frames = lf.render_many(demo_views[:2], budget_ms=1e6)
    assert len(frames) == 2
    for bad in (
        {"target_psnr": float("nan")},
        {"budget_ms": 0.0},
        {"target_psnr": 20.0, "budget_ms": 10.0},
        {},
    ):
        with pytest.raises(ValueError):
            lf.choose(view, **bad)
    with pytest.raises(ValueError, match="do not send them too"):
        lf.render(view, target_psnr=20.0, step=1 / 16)
    # Without calibration the goals say how to get one; the default bake has none.
    plain = lg.bake_mesh(demo_mesh, cameras=12, resolution=32, progress=False)
    with pytest.raises(ValueError, match="calibrate=True"):
        plain.render(view, budget_ms=100.0)
    # The calibration survives save / open.
    assert lg.LightField.from_bytes(lf.to_bytes()).choose(view, budget_ms=1e6) == roomy


def _view_at(lf: lg.LightField, px: float, size: int) -> lg.View:
    """A view in which the bounding sphere projects to ``px`` pixels across."""
    (cx, cy, cz), r = lf.bounding_sphere
    f = size / 2 / np.tan(np.radians(20.0))
    d = r * np.sqrt(1.0 + (2.0 * f / px) ** 2)
    return lg.View(
        eye=(cx, cy + 0.3 * d, cz + d * np.sqrt(1 - 0.09)),
        target=(cx, cy, cz),
        yfov_deg=40.0,
        width=size,
        height=size,
    )


def test_auto_lod_picks_by_projected_size_and_renders_the_choice(
    calibrated_lf: lg.LightField, demo_mesh: lg.Mesh
) -> None:
    lf = calibrated_lf
    points = lf.info["quality"]["calibration"]["points"]
    assert all(p["silhouette_error"] > 0 for p in points)
    small = lf.choose_lod(_view_at(lf, 20.0, 128), lod_blend=0.0)
    large = lf.choose_lod(_view_at(lf, 400.0, 128), lod_blend=0.0)
    # The projected size follows the tangent-cone formula (1e-9 relative).
    assert small["projected_px"] == pytest.approx(20.0, rel=1e-9)
    assert large["projected_px"] == pytest.approx(400.0, rel=1e-9)
    # Small on screen: the bound is met with a level at least as coarse as for a large object.

    def level_error(choice: dict[str, Any]) -> float:
        return float(
            next(
                p["silhouette_error"]
                for p in points
                if p["cameras"] == choice["cameras"] and abs(p["step"] - choice["step"]) < 1e-7
            )
        )

    small_e, large_e = level_error(small), level_error(large)
    assert small["met"] is True and small["error_px"] <= 1.0
    assert small["error_px"] == pytest.approx(small_e * 20.0)
    assert small_e >= large_e
    assert small["blend"] is None
    # render(auto_lod=...) renders exactly the decision (no blend with lod_blend=0).
    view = _view_at(lf, 60.0, 96)
    d = lf.choose_lod(view, lod_blend=0.0)
    auto = lf.render(view, auto_lod=1.0, lod_blend=0.0)
    explicit = lf.render(view, lod=d["cameras"], step=d["step"])
    np.testing.assert_array_equal(auto.color, explicit.color)
    np.testing.assert_array_equal(auto.depth, explicit.depth)
    assert len(lf.render_many([view, view], auto_lod=1.0)) == 2
    # Pinned knobs are kept.
    pinned = lf.choose_lod(view, lod=12)
    assert pinned["cameras"] == 12
    # Bad policies, conflicts and uncalibrated light fields fail clearly.
    bads: list[dict[str, Any]] = [
        {"auto_lod": 0.0},
        {"auto_lod": float("nan")},
        {"auto_lod": 1.0, "lod_blend": 2.0},
    ]
    for bad in bads:
        with pytest.raises(ValueError):
            lf.render(view, **bad)
    with pytest.raises(ValueError, match="not both"):
        lf.render(view, auto_lod=1.0, budget_ms=50.0)
    with pytest.raises(ValueError, match="need auto_lod"):
        lf.render(view, lod_blend=0.1)
    with pytest.raises(ValueError, match="default-method"):
        lf.render(view, auto_lod=1.0, method="fixed")
    plain = lg.bake_mesh(demo_mesh, cameras=12, resolution=32, progress=False)
    with pytest.raises(ValueError, match="calibrate=True"):
        plain.render(view, auto_lod=1.0)


def test_guide_renders_the_same_scene_with_less_work(demo_lf: lg.LightField) -> None:
    view = _view_at(demo_lf, 150.0, 128)
    plain = demo_lf.render(view, guide=0)
    guided = demo_lf.render(view, guide=4)
    # Coverage within 2 % and the work (fetches, coarse pass included) lower; guide 4 is the
    # default method's default.
    assert demo_lf.render(view).stats["fetches"] == guided.stats["fetches"]
    assert abs(int(guided.coverage.sum()) - int(plain.coverage.sum())) <= 0.02 * plain.coverage.sum()
    assert guided.stats["fetches"] < plain.stats["fetches"]
    for bad in (1, 17):
        with pytest.raises(ValueError, match="guide"):
            demo_lf.render(view, guide=bad)
    with pytest.raises(ValueError, match="default method"):
        demo_lf.render(view, guide=4, method="fixed")
