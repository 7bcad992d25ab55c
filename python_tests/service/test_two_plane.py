"""A two-plane light field through the service (DESIGN §9, docs/two_plane.md): upload, listing with
its planes, renders with `uv_filter`, `focus` and `aperture` in a POST body and in a render link
(equal to the CLI's frames), refusals of the other kind's keys, and a stream session whose resting
frames are depth-corrected and whose settings take the same keys."""

from __future__ import annotations

import asyncio
import io
import json
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from conftest import BIN, Server, runtime_env
from test_stream import Frame, open_session

ASSET = "tp-demo"
# The demo's bounding sphere has radius 3.55 about the origin; `auto` along +z puts the st plane
# through the centre and the uv plane at z = 10.65: this eye is beyond it, looking back.
VIEW: dict[str, Any] = {"eye": [0.4, 0.3, 14.0], "target": [0, 0, 0], "up": [0, 1, 0],
                        "yfov_deg": 30, "width": 96, "height": 80}


def lumigraph(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN), *args], capture_output=True, text=True, env=runtime_env(),
                          timeout=300, check=False)


@pytest.fixture(scope="module")
def two_plane_lfa(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("two-plane") / "tp.lfa"
    baked = lumigraph("bake", "--demo", "-o", str(out), "--two-plane", "auto", "--axis", "0,0,1",
                      "--grid", "5x5", "--st-res", "64x64")
    assert baked.returncode == 0, baked.stderr
    return out


@pytest.fixture
def uploaded(server: Server, two_plane_lfa: Path) -> Iterator[str]:
    created = httpx.post(f"{server.base_url}/v1/assets?id={ASSET}",
                         content=two_plane_lfa.read_bytes(), timeout=60)
    assert created.status_code == 201, created.text
    try:
        yield ASSET
    finally:
        httpx.delete(f"{server.base_url}/v1/assets/{ASSET}", timeout=30)


def rgba(content: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(content)).convert("RGBA"))


def cli_frame(lfa: Path, tmp: Path, *flags: str) -> np.ndarray:
    view = tmp / "view.json"
    view.write_text(json.dumps(VIEW))
    png = tmp / "cli.png"
    done = lumigraph("render", str(lfa), "--view", str(view), "-o", str(png), *flags)
    assert done.returncode == 0, done.stderr
    return np.asarray(Image.open(png).convert("RGBA"))


def test_listing_shows_the_kind_planes_and_memory(server: Server, uploaded: str) -> None:
    summary = httpx.get(f"{server.base_url}/v1/assets/{uploaded}", timeout=10).json()
    assert summary["kind"] == "two_plane"
    assert summary["camera_count"] == 25 and summary["resolution_px"] == 64
    planes = summary["planes"]
    assert planes["uv"]["grid"] == [5, 5] and planes["st"]["resolution"] == [64, 64]
    # RGBA8 per texel + R32F per texel of the depth pyramid (64² down to 1²), 25 layers (no
    # padding needed): what the budget is charged.
    pyramid = sum((64 >> level) ** 2 for level in range(7))
    assert summary["gpu_bytes"] == 25 * (64 * 64 * 4 + pyramid * 4)
    listed = {a["id"]: a for a in httpx.get(f"{server.base_url}/v1/assets", timeout=10).json()}
    assert listed[uploaded]["kind"] == "two_plane"
    demo = httpx.get(f"{server.base_url}/v1/assets/demo", timeout=10).json()
    assert demo["kind"] == "spherical" and "planes" not in demo


@pytest.mark.parametrize("flags", [
    {},
    {"uv_filter": "nearest"},
    {"uv_filter": "depth"},
    {"uv_filter": "bilinear", "focus": 1.5},
    {"aperture": 1, "focus": -0.5, "refine": 4},
])
def test_http_renders_equal_the_cli(server: Server, uploaded: str, two_plane_lfa: Path,
                                    tmp_path: Path, flags: dict[str, Any]) -> None:
    """The same GPU code renders both: the frames agree to the byte (PNG is lossless). The
    decision headers say what was rendered."""
    response = httpx.post(f"{server.base_url}/v1/assets/{uploaded}/render",
                          json={"view": VIEW, "format": "png", **flags}, timeout=60)
    assert response.status_code == 200, response.text
    served = rgba(response.content)
    cli_flags: list[str] = []
    for key, value in flags.items():
        cli_flags += [f"--{key.replace('_', '-')}", str(value)]
    expected = cli_frame(two_plane_lfa, tmp_path, *cli_flags)
    assert served.shape == expected.shape == (80, 96, 4)
    assert (served[..., 3] > 0).sum() > 500, "the object is in view"
    assert np.array_equal(served, expected), np.abs(
        served.astype(int) - expected.astype(int)).max()
    assert response.headers["x-uv-filter"] == flags.get("uv_filter", "bilinear")
    assert float(response.headers["x-focus"]) == flags.get("focus", 0)
    assert float(response.headers["x-aperture"]) == flags.get("aperture", 0)
    assert response.headers["x-aperture-draws"] == str(flags.get("refine", 1))


def test_render_link_takes_the_two_plane_keys(server: Server, uploaded: str) -> None:
    query = ("eye=0.4,0.3,14&target=0,0,0&yfov_deg=30&width=96&height=80&format=png"
             "&uv_filter=depth&focus=1&aperture=0.5")
    link = httpx.get(f"{server.base_url}/v1/assets/{uploaded}/render?{query}", timeout=60)
    assert link.status_code == 200, link.text
    posted = httpx.post(f"{server.base_url}/v1/assets/{uploaded}/render", timeout=60, json={
        "view": VIEW, "format": "png", "uv_filter": "depth", "focus": 1, "aperture": 0.5})
    assert np.array_equal(rgba(link.content), rgba(posted.content))
    bad = httpx.get(f"{server.base_url}/v1/assets/{uploaded}/render?{query.replace('depth', 'blurry')}",
                    timeout=30)
    assert bad.status_code == 422 and "uv_filter" in bad.text, bad.text


@pytest.mark.parametrize(("asset", "body", "needle"), [
    (ASSET, {"lod": 12}, "lod apply to spherical light fields"),
    (ASSET, {"step": 0.01, "light": [0, 1, 0]}, "step, light apply to spherical"),
    (ASSET, {"aperture": -1}, "aperture"),
    (ASSET, {"aperture": 65}, "aperture"),
    (ASSET, {"uv_filter": "blurry"}, "uv_filter"),
    (ASSET, {"refine": 0}, "refine"),
    ("demo", {"focus": 1}, "focus apply to two-plane light fields; this asset is spherical"),
    ("demo", {"uv_filter": "depth", "aperture": 2}, "uv_filter, aperture apply to two-plane"),
])
def test_keys_of_the_other_kind_are_422(server: Server, uploaded: str, asset: str,
                                        body: dict[str, Any], needle: str) -> None:
    response = httpx.post(f"{server.base_url}/v1/assets/{asset}/render",
                          json={"view": VIEW, **body}, timeout=30)
    assert response.status_code == 422, response.text
    assert needle in response.json()["error"]["message"], response.text


def test_focus_moves_the_sharp_plane(server: Server, uploaded: str) -> None:
    """A wide aperture focused on the object (the st plane through its centre) keeps it sharper
    than one focused far in front of it: the gradient energy of the frame drops."""
    def energy(focus: float) -> float:
        response = httpx.post(f"{server.base_url}/v1/assets/{uploaded}/render", timeout=60, json={
            "view": {**VIEW, "width": 128, "height": 128}, "format": "png", "aperture": 2,
            "focus": focus, "refine": 2, "background": [0, 0, 0, 255]})
        assert response.status_code == 200, response.text
        grey = rgba(response.content)[..., :3].astype(float).mean(axis=2)
        return float((np.diff(grey, axis=0) ** 2).sum() + (np.diff(grey, axis=1) ** 2).sum())
    assert energy(0.0) > 1.2 * energy(5.0)


def test_stream_session_on_a_two_plane_asset(server: Server, uploaded: str) -> None:
    async def body() -> None:
        s = await open_session(server, uploaded)
        assert s.hello["asset"]["kind"] == "two_plane"
        assert s.hello["asset"]["planes"]["uv"]["grid"] == [5, 5]
        await s.send({"type": "settings", "interactive": False, "still_codec": "png"})
        await s.view(1, VIEW, still=True)
        still = await s.frame(lambda f: f.request_id == 1 and f.quality == 1)
        # Resting frames default to the depth-corrected filter (depth was captured).
        depth = httpx.post(f"{server.base_url}/v1/assets/{uploaded}/render", timeout=60, json={
            "view": VIEW, "format": "png", "uv_filter": "depth"})
        assert np.array_equal(frame_rgba(still), rgba(depth.content))
        # The two-plane keys are stream settings; the spherical ones are refused, socket open.
        await s.send({"type": "settings", "aperture": 1, "focus": 0.5})
        wide = await s.frame(lambda f: f.frame_id > still.frame_id)
        posted = httpx.post(f"{server.base_url}/v1/assets/{uploaded}/render", timeout=60, json={
            "view": VIEW, "format": "png", "aperture": 1, "focus": 0.5})
        assert np.array_equal(frame_rgba(wide), rgba(posted.content))
        for refused, needle in [({"lod": 12}, "apply to spherical"),
                                ({"interactive_lod": 12}, "interactive_lod"),
                                ({"aperture": 100}, "aperture")]:
            await s.send({"type": "settings", **refused})
            error = await s.error()
            assert error["kind"] == "invalid" and needle in error["message"], error
        await s.view(2, VIEW, still=True)
        again = await s.frame(lambda f: f.request_id == 2)
        assert np.array_equal(frame_rgba(again), frame_rgba(wide)), "refused settings left no trace"
        await s.ws.close()

    asyncio.run(asyncio.wait_for(body(), timeout=120))


def frame_rgba(frame: Frame) -> np.ndarray:
    return np.asarray(frame.decode().convert("RGBA"))
