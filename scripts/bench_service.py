#!/usr/bin/env python3
"""Benchmark of the render service's stream (a benchmark, not a timed test).

Starts `lumigraph serve` on a free loopback port in a temporary assets folder (the default demo
bake: 162 cameras, 256 px maps), then over `/v1/stream`:

- request-to-frame latency (p50/p95) of 512x512 full-quality frames for 1, 4 and 16 concurrent
  clients, each a closed loop (send a `still` view of a new orbit angle, wait for its frame, ack,
  repeat), and frames per second per client;
- bytes and encode ms per 512x512 frame for each codec (png, jpeg q90, webp lossless).

Run by scripts/bench_all.sh (with a venv of httpx, websockets and pillow), or alone:
`PY scripts/bench_service.py [--out out/bench_service.md]`. Writes a markdown report and prints it.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import platform
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from websockets.asyncio.client import ClientConnection, connect

ROOT = Path(__file__).resolve().parent.parent
HEADER = struct.Struct("<4sHBBIIIIffIHH")
SIZE = 512


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def view(angle: float, radius: float) -> dict[str, Any]:
    d = radius * 2.8
    return {"eye": [d * math.sin(angle), 0.3 * d, d * math.cos(angle)], "target": [0, 0, 0],
            "up": [0, 1, 0], "yfov_deg": 40, "width": SIZE, "height": SIZE}


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


class Client:
    def __init__(self, ws: ClientConnection, radius: float) -> None:
        self.ws = ws
        self.radius = radius
        self.next_id = 1

    @classmethod
    async def open(cls, url: str, settings: dict[str, Any]) -> Client:
        ws = await connect(url, max_size=64 << 20)
        hello = json.loads(await ws.recv())
        await ws.send(json.dumps({"type": "settings", **settings}))
        return cls(ws, float(hello["asset"]["radius"]))

    async def frame(self, angle: float) -> tuple[float, tuple[Any, ...], int]:
        """Sends a still view and waits for its frame: (latency ms, header, image bytes)."""
        request = self.next_id
        self.next_id += 1
        start = time.perf_counter()
        await self.ws.send(json.dumps({"type": "view", "id": request,
                                       "view": view(angle, self.radius), "still": True}))
        while True:
            message = await self.ws.recv()
            if isinstance(message, str):
                raise RuntimeError(f"server error: {message}")
            header = HEADER.unpack_from(message)
            await self.ws.send(json.dumps({"type": "ack", "frame": header[4]}))
            if header[5] == request:
                return (time.perf_counter() - start) * 1e3, header, len(message) - header[1]


async def closed_loops(conns: list[Client], seconds: float, warm_s: float = 1.0
                       ) -> tuple[list[float], list[float], list[float]]:
    """Every client in a closed loop (a new orbit angle, its frame, ack, repeat) for `warm_s`
    unrecorded, then `seconds` recorded; closes them. Returns (latencies ms, render ms, fps per
    client)."""
    latencies: list[float] = []
    render_ms: list[float] = []
    counts = [0] * len(conns)

    async def loop(index: int, until: float, record: bool) -> None:
        angle = index * 0.7
        while time.perf_counter() < until:
            angle += 0.05
            ms, header, _ = await conns[index].frame(angle)
            if record:
                latencies.append(ms)
                render_ms.append(header[8])
                counts[index] += 1

    warm = time.perf_counter() + warm_s
    await asyncio.gather(*(loop(i, warm, False) for i in range(len(conns))))
    start = time.perf_counter()
    await asyncio.gather(*(loop(i, start + seconds, True) for i in range(len(conns))))
    elapsed = time.perf_counter() - start
    for c in conns:
        await c.ws.close()
    return latencies, render_ms, [n / elapsed for n in counts]


async def latency_level(url: str, clients: int, seconds: float) -> dict[str, Any]:
    conns = [await Client.open(url, {"interactive": False, "still_codec": "jpeg"})
             for _ in range(clients)]
    latencies, render_ms, fps = await closed_loops(conns, seconds)
    return {"clients": clients, "frames": len(latencies), "p50": pct(latencies, 0.5),
            "p95": pct(latencies, 0.95), "fps_mean": statistics.mean(fps), "fps_min": min(fps),
            "fps_max": max(fps), "render_p50": pct(render_ms, 0.5)}


async def codec_level(url: str, codec: str, frames: int) -> dict[str, Any]:
    client = await Client.open(url, {"interactive": False, "still_codec": codec})
    for i in range(3):
        await client.frame(i * 0.1)
    sizes, encode, render = [], [], []
    for i in range(frames):
        _, header, nbytes = await client.frame(0.3 + i * 0.05)
        assert header[2] == {"png": 0, "jpeg": 1, "webp": 2}[codec]
        sizes.append(nbytes)
        render.append(header[8])
        encode.append(header[9])
    await client.ws.close()
    return {"codec": codec, "frames": frames, "bytes": statistics.mean(sizes),
            "encode_p50": pct(encode, 0.5), "encode_p95": pct(encode, 0.95),
            "render_p50": pct(render, 0.5)}


def start_server(assets: Path, port: int, log: Path) -> subprocess.Popen[bytes]:
    binary = Path(os.environ.get("LUMIGRAPH_BIN") or ROOT / "target" / "release" / "lumigraph")
    env = dict(os.environ)
    env.pop("LUMIGRAPH_TOKEN", None)
    proc = subprocess.Popen([str(binary), "serve", "--assets", str(assets), "--addr",
                             f"127.0.0.1:{port}"], stdout=log.open("wb"),
                            stderr=subprocess.STDOUT, env=env)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"server exited:\n{log.read_text()[-3000:]}")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200:
                return proc
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise SystemExit("server not ready after 300 s")


def finish_report(out: Path, lines: list[str], code: int) -> None:
    """Writes the report's lines to `out`, prints them and exits non-zero when the server's
    exit `code` after SIGTERM was not 0."""
    report = "\n".join(lines)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(report)
    print(report)
    if code != 0:
        sys.exit(f"server exited with {code}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench_service.md")
    parser.add_argument("--seconds", type=float, default=8.0, help="measured time per level")
    parser.add_argument("--clients", default="1,4,16")
    parser.add_argument("--codec-frames", type=int, default=20)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        started = time.monotonic()
        proc = start_server(Path(tmp) / "assets", port, Path(tmp) / "server.log")
        bake_s = time.monotonic() - started
        try:
            base = f"http://127.0.0.1:{port}"
            ready = httpx.get(f"{base}/readyz").json()
            asset = httpx.get(f"{base}/v1/assets").json()[0]
            url = f"ws://127.0.0.1:{port}/v1/stream?asset={asset['id']}"
            levels = [asyncio.run(latency_level(url, int(n), args.seconds))
                      for n in args.clients.split(",")]
            codecs = [asyncio.run(codec_level(url, c, args.codec_frames))
                      for c in ("png", "jpeg", "webp")]
            dropped = 0.0
            for line in httpx.get(f"{base}/metrics").text.splitlines():
                if line.startswith("lumigraph_dropped_frames_total"):
                    dropped = float(line.split()[-1])
        finally:
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(timeout=30)

    lines = [
        "## Render service: streaming (scripts/bench_service.py)",
        "",
        f"Machine: {os.cpu_count()} CPU cores, {platform.machine()}, adapter: "
        f"{ready['adapter']}. Asset: the built-in demo, {asset['camera_count']} cameras, "
        f"{asset['resolution_px']} px maps (startup incl. demo bake {bake_s:.1f} s). "
        f"Frames {SIZE}x{SIZE}, full quality (`interactive: false`, `still: true`), "
        f"render workers 2; each client is a closed loop (view → its frame → ack → next view) "
        f"over loopback; {args.seconds:.0f} s measured per row after 1 s of warm-up. Latency is "
        "from sending the view message to receiving the whole binary frame (render + encode + "
        "queueing for a render worker + transfer).",
        "",
        "| clients | frames | latency p50 (ms) | latency p95 (ms) | fps per client (mean / min / max)"
        " | render p50 (ms) |",
        "|---:|---:|---:|---:|---|---:|",
    ]
    for r in levels:
        lines.append(f"| {r['clients']} | {r['frames']} | {r['p50']:.0f} | {r['p95']:.0f} | "
                     f"{r['fps_mean']:.2f} / {r['fps_min']:.2f} / {r['fps_max']:.2f} | "
                     f"{r['render_p50']:.0f} |")
    lines += [
        "",
        f"Per codec, one client, {args.codec_frames} frames of {SIZE}x{SIZE} each (bytes = image "
        "bytes without the 40-byte frame header; encode ms from the frame header):",
        "",
        "| codec | bytes per frame (mean) | encode p50 (ms) | encode p95 (ms) | render p50 (ms) |",
        "|---|---:|---:|---:|---:|",
    ]
    for c in codecs:
        name = {"png": "png", "jpeg": "jpeg q90", "webp": "webp (lossless)"}[c["codec"]]
        lines.append(f"| {name} | {c['bytes'] / 1024:.1f} KiB | {c['encode_p50']:.1f} | "
                     f"{c['encode_p95']:.1f} | {c['render_p50']:.0f} |")
    lines += ["", f"Dropped frames during the run: {dropped:.0f} (closed-loop clients never "
              f"outrun the server). Server exit code after SIGTERM: {code}.", ""]
    finish_report(args.out, lines, code)


if __name__ == "__main__":
    main()
