"""A two-plane light field larger than `serve --cache-mib` renders through a paged cache
(docs/two_plane.md "Paged rendering"): the listing shows the cache and charges its bytes, frames
report their faults and degraded pixels in headers and `/metrics`, a view at rest converges to the
frame of the fully resident asset bit for bit, the stream renders through the same cache, and a
page that fails to read while serving degrades that frame, is logged and counted, and leaves the
server up."""

from __future__ import annotations

import asyncio
import io
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

from conftest import Server, metric, running_server
from test_stream import open_session
from test_two_plane import VIEW, cli_frame, two_plane_lfa  # noqa: F401 (a fixture)

# The asset (5x5 cameras of 64² px, one 64² page each: 25 pages, 800 KiB resident) through a
# 0.4 MiB cache: a 4x coarse level (50 KiB) and 11 slots of 32 KiB.
CACHE_MIB = "0.4"
PAGES_PER_FRAME = 3
PAGE_BYTES = 64 * 64 * 8


@pytest.fixture(scope="module")
def paged_server(tmp_path_factory: pytest.TempPathFactory, demo_lfa: Path) -> Iterator[Server]:
    with running_server(
        tmp_path_factory.mktemp("paged-server"), demo_lfa,
        extra=["--cache-mib", CACHE_MIB, "--prefetch", "predict",
               "--pages-per-frame", str(PAGES_PER_FRAME)],
    ) as s:
        yield s


def upload(server: Server, lfa: Path, asset: str) -> dict[str, Any]:
    created = httpx.post(f"{server.base_url}/v1/assets?id={asset}", content=lfa.read_bytes(),
                         timeout=60)
    assert created.status_code == 201, created.text
    return dict(created.json())


def render(server: Server, asset: str, view: dict[str, Any]) -> httpx.Response:
    response = httpx.post(f"{server.base_url}/v1/assets/{asset}/render", timeout=60,
                          json={"view": view, "format": "png"})
    assert response.status_code == 200, response.text
    return response


def rgba(content: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(content)).convert("RGBA"))


def metrics(server: Server) -> str:
    return httpx.get(f"{server.base_url}/metrics", timeout=10).text


def test_paged_asset_converges_to_the_resident_frame_and_reports_its_pages(
    paged_server: Server, two_plane_lfa: Path, tmp_path: Path
) -> None:
    summary = upload(paged_server, two_plane_lfa, "tp-paged")
    cache = summary["page_cache"]
    assert cache["prefetch"] == "predict" and cache["pages_per_frame"] == PAGES_PER_FRAME
    assert cache["pages"] == 25 and cache["page_size"] == 64 and 0 < cache["slots"] < 25
    assert cache["resident_bytes"] == 25 * PAGE_BYTES
    # The asset is charged its cache, not its resident size.
    assert summary["gpu_bytes"] == cache["device_bytes"] < cache["resident_bytes"]
    demo = httpx.get(f"{paged_server.base_url}/v1/assets/demo", timeout=10).json()
    assert "page_cache" not in demo, "spherical assets stay resident"

    replies = [render(paged_server, "tp-paged", VIEW)]
    while int(replies[-1].headers["x-degraded-px"]) > 0 and len(replies) < 12:
        replies.append(render(paged_server, "tp-paged", VIEW))
    first = replies[0]
    assert int(first.headers["x-degraded-px"]) > 0, "3 pages per frame leave the first degraded"
    assert int(first.headers["x-page-faults"]) > PAGES_PER_FRAME
    assert int(first.headers["x-pages-loaded"]) == PAGES_PER_FRAME
    # The frame that loaded the last pages it needed is whole (pages load before the frame
    # renders) but counts them as faults; the next one finds them all resident.
    assert int(replies[-1].headers["x-degraded-px"]) == 0
    replies.append(render(paged_server, "tp-paged", VIEW))
    last = replies[-1]
    assert [int(last.headers[h]) for h in ("x-degraded-px", "x-page-faults", "x-pages-loaded")] \
        == [0, 0, 0]
    # The CLI's paged renderer with every page resident: the reference, bit for bit.
    expected = cli_frame(two_plane_lfa, tmp_path, "--report", str(tmp_path / "report.json"))
    assert np.array_equal(rgba(last.content), expected)
    assert not np.array_equal(rgba(first.content), expected), "the coarse level shows"

    text = metrics(paged_server)
    faults = sum(int(r.headers["x-page-faults"]) for r in replies)
    loaded = sum(int(r.headers["x-pages-loaded"]) for r in replies)
    degraded = sum(int(r.headers["x-degraded-px"]) for r in replies)
    assert metric(text, "lumigraph_page_cache_faults_total") == faults
    assert metric(text, "lumigraph_page_cache_pages_loaded_total") == loaded
    assert metric(text, "lumigraph_page_cache_uploaded_bytes_total") == loaded * PAGE_BYTES
    assert metric(text, "lumigraph_page_cache_degraded_pixels_total") == degraded
    assert metric(text, "lumigraph_page_cache_degraded_frames_total") == len(replies) - 2
    # This view spans less than a texel a pixel: no overview pixels.
    assert all(int(r.headers["x-overview-px"]) == 0 for r in replies)
    assert metric(text, "lumigraph_page_cache_overview_pixels_total") == 0
    assert metric(text, "lumigraph_page_cache_hits_total") > 0

    async def stream() -> None:
        s = await open_session(paged_server, "tp-paged")
        await s.send({"type": "settings", "interactive": False, "still_codec": "png",
                      "uv_filter": "bilinear"})
        await s.view(1, VIEW, still=True)
        frame = await s.frame(lambda f: f.request_id == 1 and f.quality == 1)
        assert np.array_equal(np.asarray(frame.decode().convert("RGBA")), expected)
        await s.ws.close()

    asyncio.run(asyncio.wait_for(stream(), timeout=60))
    after = metrics(paged_server)
    assert metric(after, "lumigraph_page_cache_hits_total") > metric(
        text, "lumigraph_page_cache_hits_total"), "the stream rendered through the cache"


def test_a_page_failing_to_read_degrades_the_frame_and_the_server_stays_up(
    paged_server: Server, two_plane_lfa: Path
) -> None:
    upload(paged_server, two_plane_lfa, "tp-corrupt")
    render(paged_server, "tp-corrupt", VIEW)
    before = metric(metrics(paged_server), "lumigraph_page_cache_read_errors_total")
    # Corrupt the pages on disk under the running server (its header and index are in memory):
    # every page not resident yet now fails its checksum when a frame needs it.
    path = paged_server.assets / "tp-corrupt.lfa"
    data = bytearray(path.read_bytes())
    for i in range(len(data) // 10, len(data) * 9 // 10):
        data[i] ^= 0xA5
    with path.open("r+b") as f:
        f.write(data)
    side = {**VIEW, "eye": [-6.0, -4.0, 14.0]}
    degraded = render(paged_server, "tp-corrupt", side)
    assert int(degraded.headers["x-degraded-px"]) > 0
    assert metric(metrics(paged_server), "lumigraph_page_cache_read_errors_total") > before
    assert "page read failed" in paged_server.log_tail(200)
    assert httpx.get(f"{paged_server.base_url}/readyz", timeout=10).status_code == 200
    # The frame's resident pages still render, and other assets are untouched.
    render(paged_server, "tp-corrupt", VIEW)
    render(paged_server, "demo", {"eye": [0, 1, 10], "target": [0, 0, 0], "up": [0, 1, 0],
                                  "yfov_deg": 40, "width": 64, "height": 64})
