"""The web viewer in real headless Chromium (Debian's `chromium`, driven by playwright with
`executable_path`; no browser download): the page loads, a frame is drawn, a drag changes the
frame and the stats overlay updates."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import Page, sync_playwright

from conftest import Server

CHROMIUM = Path(os.environ.get("LUMIGRAPH_CHROMIUM", "/usr/bin/chromium"))

CANVAS_PIXELS = """() => {
  const c = document.getElementById('view');
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  let lit = 0, sum = 0;
  for (let i = 0; i < d.length; i += 4) { sum += d[i] + d[i + 1] + d[i + 2]; if (d[i + 3]) lit++; }
  return {w: c.width, h: c.height, lit, sum, url: c.toDataURL('image/png')};
}"""
FRAMES = "Number(document.getElementById('stats').dataset.frames)"


@pytest.fixture
def page(server: Server) -> Iterator[Page]:
    if not CHROMIUM.is_file():
        pytest.fail(f"{CHROMIUM} is missing: apt-get install chromium")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                    args=["--no-sandbox", "--disable-dev-shm-usage"])
        try:
            context = browser.new_context(viewport={"width": 900, "height": 600})
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            # Every failed request but the browser's own favicon probe (the viewer has none).
            page.on("response", lambda r: errors.append(f"{r.status} {r.url}")
                    if r.status >= 400 and not r.url.endswith("/favicon.ico") else None)
            page.errors = errors  # type: ignore[attr-defined]
            yield page
            context.close()
        finally:
            browser.close()


def canvas(page: Page) -> dict[str, Any]:
    result: dict[str, Any] = page.evaluate(CANVAS_PIXELS)
    result["hash"] = hashlib.sha256(result.pop("url").encode()).hexdigest()
    return result


def last(page: Page) -> dict[str, Any]:
    value: dict[str, Any] = page.evaluate(
        "() => ({...window.lumigraphViewer.last, frames: window.lumigraphViewer.frames,"
        " requestId: window.lumigraphViewer.requestId})")
    return value


def test_viewer_loads_draws_and_follows_a_drag(server: Server, page: Page) -> None:
    sent: list[str] = []
    page.on("websocket", lambda ws: ws.on(
        "framesent", lambda payload: sent.append(payload) if isinstance(payload, str) else None))
    page.goto(server.base_url + "/")
    assert page.title() == "lumigraph viewer"
    page.wait_for_function(f"{FRAMES} >= 1", timeout=30_000)
    # The asset picker lists the demo; the lod control is filled from the hello message.
    assert page.eval_on_selector_all("#asset option", "os => os.map(o => o.value)") == ["demo"]
    assert page.eval_on_selector_all("#lod option", "os => os.map(o => o.value)") == ["12"]
    # The first frame is a full-quality frame (the viewer asks for a still first) and is drawn.
    page.wait_for_function("window.lumigraphViewer.last && window.lumigraphViewer.last.quality === 1",
                           timeout=30_000)
    first = last(page)
    before = canvas(page)
    assert before["w"] > 100 and before["h"] > 100
    assert before["lit"] == before["w"] * before["h"]  # opaque background colour everywhere
    assert before["sum"] > 0
    stats = page.inner_text("#stats")
    for field in ("fps", "render", "encode", "latency", "bytes", "quality", "cameras", "frames"):
        assert field in stats, stats
    assert page.get_attribute("#stats", "data-quality") == "full"
    frames_before = int(page.get_attribute("#stats", "data-frames") or 0)

    # Drag across the canvas: interactive frames while moving, then a full frame for the new view.
    box = page.locator("#view").bounding_box()
    assert box is not None
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    for i in range(1, 11):
        page.mouse.move(x + 18 * i, y + 4 * i)
        page.wait_for_timeout(30)
    page.mouse.up()
    page.wait_for_function(
        f"window.lumigraphViewer.last.requestId > {first['requestId']}"
        " && window.lumigraphViewer.last.requestId === window.lumigraphViewer.requestId"
        " && window.lumigraphViewer.last.quality === 1", timeout=30_000)
    after = canvas(page)
    moved = last(page)
    assert after["hash"] != before["hash"], "the drag did not change the drawn frame"
    assert moved["frames"] > first["frames"]
    assert moved["dropped"] >= 0 and moved["renderMs"] > 0
    # The stats overlay followed: frame count, quality and the frame's numbers.
    frames_after = int(page.get_attribute("#stats", "data-frames") or 0)
    assert frames_after > frames_before
    stats_after = page.inner_text("#stats")
    assert stats_after != stats
    assert f"frames    {frames_after}" in stats_after
    assert page.get_attribute("#stats", "data-quality") == "full"
    assert not page.errors, page.errors  # type: ignore[attr-defined]
    # Every frame drawn was acked with its receive time (the server measures the link from
    # them): one ack per frame, in order, times from the page's steady clock, never decreasing.
    acks = [m for m in map(json.loads, sent) if m["type"] == "ack"]
    assert [a["frame"] for a in acks] == list(range(1, len(acks) + 1)), acks
    assert len(acks) >= frames_after
    times = [a["received_ms"] for a in acks]
    assert all(isinstance(t, (int, float)) and t >= 0 for t in times), times
    assert times == sorted(times), times


def test_viewer_wheel_zoom_and_settings(server: Server, page: Page) -> None:
    page.goto(server.base_url + "/")
    page.wait_for_function("window.lumigraphViewer.last && window.lumigraphViewer.last.quality === 1",
                           timeout=30_000)
    first = last(page)
    before = canvas(page)
    distance = page.evaluate("window.lumigraphViewer.distance")
    box = page.locator("#view").bounding_box()
    assert box is not None
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.wheel(0, -400)
    page.wait_for_function(
        f"window.lumigraphViewer.last.requestId > {first['requestId']}"
        " && window.lumigraphViewer.last.quality === 1", timeout=30_000)
    assert page.evaluate("window.lumigraphViewer.distance") < distance
    assert canvas(page)["hash"] != before["hash"]
    # Switching the resting codec to PNG: the next full frame arrives as PNG (codec 0).
    page.select_option("#still_codec", "png")
    page.wait_for_function(
        "window.lumigraphViewer.last.codec === 0 && window.lumigraphViewer.last.quality === 1",
        timeout=30_000)
    # Automatic LOD on: the next full frame arrives and no error is shown.
    frame_id = last(page)["frameId"]
    page.fill("#auto_lod", "1")
    page.dispatch_event("#auto_lod", "change")
    page.wait_for_function(
        f"window.lumigraphViewer.last.frameId > {frame_id}"
        " && window.lumigraphViewer.last.quality === 1", timeout=30_000)
    assert not page.locator("#error").is_visible(), page.locator("#error").inner_text()
    assert not page.errors, page.errors  # type: ignore[attr-defined]
