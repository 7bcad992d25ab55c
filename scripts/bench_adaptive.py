#!/usr/bin/env python3
"""Benchmark of adaptive streaming over throttled links (a benchmark, not a timed test).

Starts `lumigraph serve` on a free loopback port (the default demo bake) and, in this process, a
loopback shaper: a TCP proxy whose server-to-client direction passes a token bucket of a given
rate (client-to-server is not limited; no added delay). For each link (direct, and each rate)
and with `adaptive` on and off, one stream client orbits continuously for `--seconds`: a view
message every 1/60 s (the server keeps the latest), every frame acked on arrival with its
receive time. Reported over the time after `--warmup`: interactive frames per second, bytes per
frame, mean JPEG quality and scale chosen (from the frame header), and motion-to-frame latency
(from sending a view to receiving the frame that shows it). Then the orbit stops and a `still`
view measures the resting frame: its codec, bytes and time to arrive.

`bash scripts/bench_adaptive.sh [--seconds 20] [--rates fast,10,2]` builds the release binary
and runs this with the e2e venv; writes out/bench_adaptive.md and prints it.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import platform
import signal
import statistics
import struct
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
from websockets.asyncio.client import connect

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_service import finish_report, free_port, pct, start_server  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
# magic, header_len, codec, quality level, frame, request, width, height, render ms, encode ms,
# dropped, cameras, JPEG quality (0: lossless), adaptation flags.
HEADER = struct.Struct("<4sHBBIIIIffIHBB")
CODECS = {0: "png", 1: "jpeg", 2: "webp"}


class TokenBucket:
    """Paces bytes to `rate` bytes/s with at most `burst` bytes sent ahead."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate = rate
        self.burst = burst
        self.tokens = burst
        self.stamp = time.perf_counter()

    async def take(self, n: int) -> None:
        while True:
            now = time.perf_counter()
            self.tokens = min(self.burst, self.tokens + (now - self.stamp) * self.rate)
            self.stamp = now
            if self.tokens >= n:
                self.tokens -= n
                return
            await asyncio.sleep((n - self.tokens) / self.rate)


async def pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
               bucket: TokenBucket | None) -> None:
    try:
        while chunk := await reader.read(4096):
            if bucket is not None:
                await bucket.take(len(chunk))
            writer.write(chunk)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        writer.close()


async def start_shaper(upstream_port: int, rate_bytes: float) -> tuple[asyncio.Server, int]:
    """A proxy to 127.0.0.1:upstream_port limiting server-to-client bytes to `rate_bytes`/s."""

    async def handle(client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        server_r, server_w = await asyncio.open_connection("127.0.0.1", upstream_port)
        # A bucket of 8 KiB: about 33 ms at 2 Mbit/s, so frames are paced, not burst.
        bucket = TokenBucket(rate_bytes, 8192)
        await asyncio.gather(pump(client_r, server_w, None), pump(server_r, client_w, bucket))

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    return server, int(server.sockets[0].getsockname()[1])


@dataclass
class Run:
    link: str
    adaptive: bool
    frames: list[dict[str, Any]] = field(default_factory=list)
    measured_s: float = 0.0
    still: dict[str, Any] = field(default_factory=dict)


def view(angle: float, radius: float, width: int, height: int) -> dict[str, Any]:
    d = radius * 2.8
    return {"eye": [d * math.sin(angle), 0.3 * d, d * math.cos(angle)], "target": [0, 0, 0],
            "up": [0, 1, 0], "yfov_deg": 40, "width": width, "height": height}


async def orbit(url: str, run: Run, args: argparse.Namespace) -> None:
    async with connect(url, max_size=64 << 20, compression=None) as ws:
        hello = json.loads(await ws.recv())
        radius = float(hello["asset"]["radius"])
        await ws.send(json.dumps({"type": "settings", "adaptive": run.adaptive,
                                  "target_fps": args.target_fps,
                                  "still_codec": args.still_codec}))
        sent_at: dict[int, float] = {}
        start = time.perf_counter()
        measure_from = start + args.warmup
        stop_at = start + args.warmup + args.seconds
        still_id = 1 << 30

        async def views() -> None:
            request = 0
            while time.perf_counter() < stop_at:
                request += 1
                angle = 0.6 * (time.perf_counter() - start)
                sent_at[request] = time.perf_counter()
                await ws.send(json.dumps({"type": "view", "id": request,
                                          "view": view(angle, radius, args.width, args.height)}))
                await asyncio.sleep(1 / 60)
            sent_at[still_id] = time.perf_counter()
            await ws.send(json.dumps({"type": "view", "id": still_id, "still": True,
                                      "view": view(0.6 * (stop_at - start), radius,
                                                   args.width, args.height)}))

        async def frames() -> None:
            async for message in ws:
                now = time.perf_counter()
                if isinstance(message, str):
                    raise RuntimeError(f"server error: {message}")
                h = HEADER.unpack_from(message)
                await ws.send(json.dumps({"type": "ack", "frame": h[4],
                                          "received_ms": now * 1e3}))
                frame = {"at": now, "bytes": len(message) - h[1], "codec": CODECS[h[2]],
                         "level": h[3], "request": h[5], "width": h[6], "height": h[7],
                         "jpeg_q": h[12], "flags": h[13],
                         "latency_ms": (now - sent_at[h[5]]) * 1e3}
                if h[5] == still_id and h[3] == 1:
                    run.still = frame
                    return
                if h[3] == 0 and measure_from <= now < stop_at:
                    run.frames.append(frame)

        await asyncio.gather(views(), frames())
        run.measured_s = args.seconds


def summary(run: Run, width: int) -> dict[str, Any]:
    f = run.frames
    if not f:
        return {"fps": 0.0}
    return {
        "fps": len(f) / run.measured_s,
        "bytes": statistics.mean(x["bytes"] for x in f),
        "kib_s": sum(x["bytes"] for x in f) / run.measured_s / 1024,
        "quality": statistics.mean(x["jpeg_q"] for x in f),
        "scale": statistics.mean(x["width"] / width for x in f),
        "limited": 100 * sum(1 for x in f if x["flags"] & 1) / len(f),
        "p50": pct([x["latency_ms"] for x in f], 0.5),
        "p95": pct([x["latency_ms"] for x in f], 0.95),
    }


async def bench(port: int, args: argparse.Namespace, asset: str) -> list[Run]:
    runs: list[Run] = []
    for link in args.rates.split(","):
        if link == "fast":
            shaper, target_port = None, port
        else:
            shaper, target_port = await start_shaper(port, float(link) * 1e6 / 8)
        for adaptive in (True, False):
            run = Run(f"{link} Mbit/s" if link != "fast" else "direct (loopback)", adaptive)
            await orbit(f"ws://127.0.0.1:{target_port}/v1/stream?asset={asset}", run, args)
            runs.append(run)
            print(f"{run.link} adaptive={adaptive}: {summary(run, args.width)}", flush=True)
        if shaper is not None:
            shaper.close()
            await shaper.wait_closed()
    return runs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench_adaptive.md")
    parser.add_argument("--seconds", type=float, default=20.0, help="measured orbit per run")
    parser.add_argument("--warmup", type=float, default=3.0, help="orbit before measuring")
    parser.add_argument("--rates", default="fast,10,2",
                        help="links: `fast` (direct) or a shaper rate in Mbit/s")
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=768)
    parser.add_argument("--target-fps", type=float, default=20.0)
    parser.add_argument("--still-codec", default="png")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        proc = start_server(Path(tmp) / "assets", port, Path(tmp) / "server.log")
        try:
            base = f"http://127.0.0.1:{port}"
            ready = httpx.get(f"{base}/readyz").json()
            asset = httpx.get(f"{base}/v1/assets").json()[0]
            runs = asyncio.run(bench(port, args, asset["id"]))
        finally:
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(timeout=30)

    lines = [
        "Machine: "
        f"{os.cpu_count()} CPU cores, {platform.machine()}, adapter: {ready['adapter']}. "
        f"Asset: the built-in demo, {asset['camera_count']} cameras, {asset['resolution_px']} px "
        f"maps. View {args.width}x{args.height}, `target_fps` {args.target_fps:g}, interactive "
        f"JPEG q50 (the default ceiling), `still_codec` {args.still_codec}; {args.seconds:g} s "
        f"measured per row after {args.warmup:g} s of orbit.",
        "",
        "| link | adaptive | fps | bytes/frame | KiB/s | JPEG q (mean) | scale (mean) "
        "| frames link-limited | motion-to-frame p50 / p95 (ms) | resting frame |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for run in runs:
        s = summary(run, args.width)
        still = run.still
        rest = (f"{still['codec']}{' (fallback)' if still['flags'] & 2 else ''}, "
                f"{still['bytes'] / 1024:.0f} KiB in {still['latency_ms']:.0f} ms"
                if still else "none")
        if s["fps"] == 0.0:
            lines.append(f"| {run.link} | {'on' if run.adaptive else 'off'} | 0 | | | | | | | "
                         f"{rest} |")
            continue
        lines.append(
            f"| {run.link} | {'on' if run.adaptive else 'off'} | {s['fps']:.1f} | "
            f"{s['bytes'] / 1024:.1f} KiB | {s['kib_s']:.0f} | {s['quality']:.0f} | "
            f"{s['scale']:.2f} | {s['limited']:.0f} % | {s['p50']:.0f} / {s['p95']:.0f} | "
            f"{rest} |")
    lines += ["", f"Server exit code after SIGTERM: {code}.", ""]
    finish_report(args.out, lines, code)


if __name__ == "__main__":
    main()
