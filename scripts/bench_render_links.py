#!/usr/bin/env python3
"""Benchmark of render links, `GET /v1/assets/{id}/render?...` (a benchmark, not a timed test).

Starts `lumigraph serve` on a free loopback port in a temporary assets folder (the default demo
bake: 162 cameras, 256 px maps), then for 512x512 links of the demo in the viewer's orbit form,
per format (png, jpeg, webp): the wall time of a full answer (render + encode + transfer, one
request at a time) against that of a revalidation (`If-None-Match` with the answer's `ETag`,
answered 304 without rendering), the image's bytes and the link's length; and checks that each
link's image equals the `POST` render of the same state.

`PY scripts/bench_render_links.py [--out out/bench_render_links.md] [--requests 20]` with a
Python that has httpx (e.g. ./.venv-e2e/bin/python). Writes a markdown report and prints it.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_service import free_port, pct, start_server  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SIZE = 512


def orbit_eye(target: list[float], az_deg: float, el_deg: float, dist: float) -> list[float]:
    az, el = math.radians(az_deg), math.radians(el_deg)
    return [target[0] + math.cos(el) * math.sin(az) * dist, target[1] + math.sin(el) * dist,
            target[2] + math.cos(el) * math.cos(az) * dist]


def measure(client: httpx.Client, base: str, asset: dict, fmt: str, requests: int) -> dict:
    target = [round(c, 6) for c in asset["center"]]
    dist = float(f"{asset['radius'] * 2.8:.6g}")
    query = (f"az=34.377&el=20.054&dist={dist}&target={','.join(map(str, target))}"
             f"&yfov_deg=40&width={SIZE}&height={SIZE}&background=32,32,32,255&format={fmt}")
    link = f"{base}/v1/assets/{asset['id']}/render?{query}"
    full_ms, cached_ms = [], []
    first = client.get(link)
    assert first.status_code == 200, first.text
    tag = first.headers["etag"]
    posted = client.post(f"{base}/v1/assets/{asset['id']}/render", json={
        "view": {"eye": orbit_eye(target, 34.377, 20.054, dist), "target": target,
                 "up": [0, 1, 0], "yfov_deg": 40, "width": SIZE, "height": SIZE},
        "background": [32, 32, 32, 255], "format": fmt})
    for _ in range(requests):
        started = time.perf_counter()
        reply = client.get(link)
        full_ms.append((time.perf_counter() - started) * 1000)
        assert reply.status_code == 200 and reply.content == first.content
        started = time.perf_counter()
        held = client.get(link, headers={"If-None-Match": tag})
        cached_ms.append((time.perf_counter() - started) * 1000)
        assert held.status_code == 304 and not held.content
    return {"format": fmt, "bytes": len(first.content), "link_chars": len(link) - len(base),
            "same_as_post": posted.content == first.content,
            "render_ms": float(first.headers["x-render-ms"]),
            "full_p50": statistics.median(full_ms), "full_p95": pct(full_ms, 0.95),
            "cached_p50": statistics.median(cached_ms), "cached_p95": pct(cached_ms, 0.95)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench_render_links.md")
    parser.add_argument("--requests", type=int, default=20, help="requests of each kind")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        proc = start_server(Path(tmp) / "assets", port, Path(tmp) / "server.log")
        try:
            base = f"http://127.0.0.1:{port}"
            adapter = httpx.get(f"{base}/readyz").json()["adapter"]
            with httpx.Client(timeout=60) as client:
                asset = client.get(f"{base}/v1/assets").json()[0]
                client.get(f"{base}/v1/assets/{asset['id']}")  # warm the connection
                rows = [measure(client, base, asset, fmt, args.requests)
                        for fmt in ("png", "jpeg", "webp")]
        finally:
            proc.send_signal(signal.SIGINT)
            code = proc.wait(timeout=30)
    lines = [
        f"Machine: {os.cpu_count()} CPU cores, {platform.machine()}, adapter: {adapter}. "
        f"Asset: {asset['id']}, {asset['camera_count']} cameras, {asset['resolution_px']} px maps. "
        f"Links of {SIZE}x{SIZE} views in the orbit form, one request at a time over loopback "
        f"(one kept-alive connection), {args.requests} of each kind per format; wall time at the "
        "client. A revalidation sends `If-None-Match` with the answer's `ETag` and gets 304.",
        "",
        "| format | image bytes | link length (chars) | = POST render | render (ms) "
        "| full answer p50 / p95 (ms) | 304 revalidation p50 / p95 (ms) |",
        "|---|---:|---:|---|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['format']} | {r['bytes'] / 1024:.1f} KiB | {r['link_chars']} "
            f"| {'yes' if r['same_as_post'] else 'NO'} | {r['render_ms']:.1f} "
            f"| {r['full_p50']:.1f} / {r['full_p95']:.1f} "
            f"| {r['cached_p50']:.2f} / {r['cached_p95']:.2f} |")
    lines += ["", f"Server exit code after SIGINT: {code}."]
    report = "\n".join(lines) + "\n"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(report)
    print(report)


if __name__ == "__main__":
    main()
