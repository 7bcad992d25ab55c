"""Benchmark of the web viewer's reprojection in headless Chromium (software GL): motion-to-photon
delay with and without reprojection behind an injected network delay, and the warped frame's
error against the true frame for rotations about the target.

    .venv-e2e/bin/python scripts/bench_reproject.py --asset out/demo.lfa [--asset out/spot.lfa]

(scripts/bench_reproject.sh bakes the assets and runs this.) Starts `lumigraph serve` (the
release binary, or $LUMIGRAPH_BIN) on a temporary folder holding the given assets, puts a
loopback TCP proxy in front of it that holds every chunk for D ms in each direction (a round
trip gains 2·D, as `tc netem delay D` on `lo` would), and drives the viewer through the proxy:

(a) motion-to-photon: after the view has settled, the camera orbits by 2° about the target (as a
    drag does); the delay is the page-clock time from the change to the first draw that shows the
    new camera, warped or the server's frame (time to screen composition is not included). Median
    and 90th percentile over --moves moves.
(b) warp error: with lossless full frames (PNG, no interactive frames) the viewer keeps one frame
    of the settled camera; it is warped to the camera rotated by 1°, 5° and 15°, and compared with
    the true frame of that camera (an HTTP render): masked PSNR (DESIGN §3), hole pixels (covered
    in the true frame, not by the warp) and the same for the unwarped frame the viewer would show
    without reprojection. Averaged over --views starting cameras.

Prints a Markdown table and writes it to --out (default out/bench_reproject.md).
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "python_tests" / "service"))
os.environ.setdefault("LUMIGRAPH_BIN", str(ROOT / "target" / "release" / "lumigraph"))

from conftest import Server  # noqa: E402
from playwright.sync_api import Page, sync_playwright  # noqa: E402
from reprojection import SETTLED, delayed, measure_warp, motion_to_photon  # noqa: E402

CHROMIUM = os.environ.get("LUMIGRAPH_CHROMIUM", "/usr/bin/chromium")
VIEWPORT = {"width": 900, "height": 600}


def open_viewer(browser: Any, url: str, asset: str) -> Page:
    page: Page = browser.new_context(viewport=VIEWPORT).new_page()
    page.goto(url)
    page.wait_for_function(SETTLED, timeout=120_000)
    if page.input_value("#asset") != asset:
        page.select_option("#asset", asset)
        page.wait_for_function(
            f"window.lumigraphViewer.asset && window.lumigraphViewer.asset.id === {asset!r}"
            f" && ({SETTLED})", timeout=120_000)
    return page


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


def latency_rows(browser: Any, server: Server, asset: str, delays: list[int],
                 moves: int) -> list[str]:
    rows = []
    for delay in delays:
        for reproject in (False, True):
            with delayed(server.port, delay) as proxy:
                query = "" if reproject else "?reproject=0"
                page = open_viewer(browser, proxy.base_url + "/" + query, asset)
                samples, kinds = [], []
                for _ in range(moves):
                    first = motion_to_photon(page, math.radians(2), timeout_ms=120_000)
                    samples.append(first["ms"])
                    kinds.append(first["kind"])
                    page.wait_for_function(SETTLED, timeout=120_000)
                    page.wait_for_timeout(200)
                warps = kinds.count("warp")
                # The settled full frame's bytes: JPEG colour, and the depth PNG when on.
                sizes = page.evaluate("""() => { const h = window.lumigraphViewer.last;
                  return h.depth ? [h.depth.colorBytes, h.depth.depthBytes] : [h.bytes - 40, 0]; }""")
                rows.append(
                    f"| {asset} | {delay} | {2 * delay} | {'on' if reproject else 'off'} "
                    f"| {statistics.median(samples):.0f} | {percentile(samples, 0.9):.0f} "
                    f"| {warps}/{len(kinds)} | {sizes[0] / 1024:.0f} + {sizes[1] / 1024:.0f} |")
                print(rows[-1], flush=True)
                page.context.close()
    return rows


def accuracy_rows(browser: Any, server: Server, asset: str, views: int) -> list[str]:
    page = open_viewer(browser, server.base_url + "/", asset)
    # Lossless full frames only: the error measured is the warp's, not the codec's.
    page.select_option("#still_codec", "png")
    page.uncheck("#interactive")
    page.wait_for_function("window.lumigraphViewer.last.codec === 0", timeout=120_000)
    rows = []
    for degrees in (1, 5, 15):
        results = []
        for k in range(views):
            # Starting cameras spread around the object (45° apart in azimuth); once no frame is
            # on its way (the rest time has passed), the kept frames are dropped and the frame of
            # the starting camera is asked for again: the warp has that one frame to work with.
            page.evaluate(f"window.lumigraphViewer.orbit({math.radians(45) if k else 0})")
            page.wait_for_function(SETTLED, timeout=120_000)
            page.wait_for_timeout(1000)
            page.evaluate("window.lumigraphViewer.warper.clear()")
            page.evaluate("window.lumigraphViewer.orbit(0)")
            page.wait_for_function(
                f"({SETTLED}) && window.lumigraphViewer.warper.sourceCount() === 1",
                timeout=120_000)
            timing = page.evaluate("""() => { const v = window.lumigraphViewer;
              const t0 = performance.now(); v.drawWarped(); return performance.now() - t0; }""")
            result = measure_warp(page, math.radians(degrees))
            result["draw_ms"] = timing
            results.append(result)

        def mean(key: str, field: str, rs: list[dict[str, Any]] = results) -> float:
            return statistics.fmean(r[key][field] for r in rs)

        covered = mean("warp", "covered")
        rows.append(
            f"| {asset} | {degrees}° | {mean('warp', 'psnr'):.2f} | {mean('stale', 'psnr'):.2f} "
            f"| {mean('warp', 'holes'):.0f} ({100 * mean('warp', 'holes') / covered:.2f} %) "
            f"| {mean('warp', 'mismatch'):.0f} | {mean('stale', 'mismatch'):.0f} "
            f"| {statistics.fmean(r['draw_ms'] for r in results):.0f} |")
        print(rows[-1], flush=True)
    page.context.close()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--asset", action="append", type=Path, required=True,
                        help=".lfa file to serve (repeatable); its stem is the asset id")
    parser.add_argument("--delays", default="50,100,200", help="one-way delays, ms")
    parser.add_argument("--moves", type=int, default=8, help="camera moves per delay")
    parser.add_argument("--views", type=int, default=4, help="starting cameras per rotation")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench_reproject.md")
    args = parser.parse_args()
    delays = [int(d) for d in args.delays.split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="lumigraph-bench-reproject-"))
    assets = tmp / "assets"
    assets.mkdir()
    for lfa in args.asset:
        shutil.copyfile(lfa, assets / lfa.name)
    ids = [lfa.stem for lfa in args.asset]
    server = Server(assets, tmp / "server.log", None, [])
    latency: list[str] = []
    accuracy: list[str] = []
    try:
        server.wait_ready(timeout=300)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                        args=["--no-sandbox", "--disable-dev-shm-usage"])
            for asset in ids:
                accuracy += accuracy_rows(browser, server, asset, args.views)
            for asset in ids:
                latency += latency_rows(browser, server, asset, delays, args.moves)
            browser.close()
    finally:
        server.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    table = "\n".join([
        "Motion-to-photon (camera change to the first drawn frame showing it; page clock, ms):",
        "",
        "| asset | one-way delay ms | added round trip ms | reprojection | median ms | p90 ms "
        "| first draw warped | full frame KiB (JPEG + depth) |",
        "|---|---|---|---|---|---|---|---|",
        *latency,
        "",
        "Warp error against the true frame (masked PSNR, DESIGN §3; mean over starting cameras):",
        "",
        "| asset | rotation | warped PSNR dB | unwarped PSNR dB | hole px (of covered) "
        "| mask mismatch px warped | unwarped | warp draw ms |",
        "|---|---|---|---|---|---|---|---|",
        *accuracy,
    ])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(table + "\n")
    print(table)


if __name__ == "__main__":
    main()
