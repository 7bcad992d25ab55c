#!/usr/bin/env python3
"""Soak test of `lumigraph serve`: well-behaved stream clients, abusive clients, uploads, deletes
and bake jobs all at once for `--seconds` (default 60), while the server's memory is sampled.

It starts the server (binary: $LUMIGRAPH_BIN, else $CARGO_TARGET_DIR/release/lumigraph, else
target/release/lumigraph) on a free loopback port in a temporary assets folder seeded with a small
demo asset (12 cameras, 64 px), with short limits so that the abuse is answered within the run
(`--stream-idle-secs 8`, `--body-timeout-secs 4`, `--header-timeout-secs 4`), and runs together:

- good clients (`--good-clients`, default 3): WebSocket sessions (docs/protocol.md) that send a
  view, ack every frame at once, and send the next view when the frame of the last one arrived
  (every 8th view waits for its full-quality frame too). Latency: from sending a view to the
  first frame that carries its id. A view without a frame in 10 s is a failure.
- abusive clients: silent sessions that send one view and then nothing, holding their session
  until the idle limit closes it (1008), then come back; messages over the 64 KiB limit (1009);
  garbage (not JSON, binary, unknown types, bad views, deep nesting) on a session that must stay
  open and still answer a good view; slow-loris uploads (a byte now and then: 408) and slow
  headers (closed); rapid connect/disconnect (WebSocket upgrades dropped at once, bare TCP).
- every 2 s an `.lfa` upload of the demo, a render of it and its delete (201, 200, 204); every
  6 s a bake job (a tetrahedron, 12 cameras, 32 px) polled to `done`, then deleted.

Every second it samples the server's RSS (VmRSS in /proc/PID/status) and the good clients' frames
per second (per client, averaged) and latency p50/p95. It writes `soak.json` (parameters,
samples, counts, summary, failures) and `soak.png` (when matplotlib is installed; otherwise the
plot is skipped with a note) to `--out`, prints a summary, and exits 1 when any of these holds:

- RSS not flat after warm-up. The run is cut in thirds; the first is warm-up (caches, allocator
  arenas, the renderer's per-size resources, the first bake's buffers). The largest RSS of the
  last third may exceed the largest of the second by at most max(10 %, 16 MiB) (`--rss-tolerance-
  pct`, `--rss-tolerance-mib`). Maxima, not means: each third holds several cycles of every
  activity (uploads every 2 s, bakes every 6 s), so a bounded server has already reached its
  steady peak in the second third, while a leak per cycle raises the last third's peak beyond
  it. Comparing two later windows rather than start and end keeps the warm-up growth out of the
  verdict (the server grows from about 123 to 128 MiB in its first minute, then by 1-2 MiB per
  minute as allocator arenas and per-size render resources settle: 130 MiB after one minute and
  after three). 16 MiB is about 7 times the growth seen between the later thirds, room for
  allocator noise on another machine; 10 % scales it for a larger server. A 60 s run so catches
  leaks from about 0.8 MiB/s (a few hundred KiB per upload, render or bake cycle); use a longer
  run for slower ones.
- any 5xx answer, a crash (the server exits during the run or not with 0 after SIGTERM), or
  `lumigraph_errors_total{kind="internal"}` above 0 at the end;
- a good client without frames in any third of the run, or a view without its frame in 10 s;
- a well-behaved request answered other than documented (upload 201, render 200, delete 204,
  bake 202 then `done`), or abuse answered other than documented (1009 for oversized messages,
  408 for stalled bodies, the garbage session closed).

Usage: scripts/soak.py [--seconds 60] [--out target/soak]; scripts/soak.sh wraps it in the e2e
venv. Needs httpx and websockets (matplotlib for the plot).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import shutil
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import websockets
from websockets.asyncio.client import ClientConnection, connect

ROOT = Path(__file__).resolve().parent.parent
HEADER = struct.Struct("<4sHBBIIIIffIHH")
FRAME_TIMEOUT_S = 10.0
TETRA_OFF = b"OFF\n4 4 0\n1 1 1\n-1 -1 1\n-1 1 -1\n1 -1 -1\n3 0 1 2\n3 0 3 1\n3 0 2 3\n3 1 3 2\n"
MIB = 1024 * 1024


def default_binary() -> Path:
    if os.environ.get("LUMIGRAPH_BIN"):
        return Path(os.environ["LUMIGRAPH_BIN"])
    target = Path(os.environ.get("CARGO_TARGET_DIR") or ROOT / "target")
    return target / "release" / "lumigraph"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rss_bytes(pid: int) -> int | None:
    """VmRSS of a process in bytes, None once it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def percentile(values: list[float], q: float) -> float | None:
    """The q-quantile (0..1) by nearest rank, None for no values."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


def rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 1)


def orbit_view(angle: float, width: int = 128, height: int = 96) -> dict[str, Any]:
    return {"eye": [10.0 * math.sin(angle), 1.0, 10.0 * math.cos(angle)], "target": [0, 0, 0],
            "up": [0, 1, 0], "yfov_deg": 40, "width": width, "height": height}


@dataclass
class Stats:
    """Everything the workers record."""

    started: float = field(default_factory=time.monotonic)
    failures: list[str] = field(default_factory=list)
    counts: Counter[str] = field(default_factory=Counter)
    http_status: Counter[str] = field(default_factory=Counter)
    frames: list[int] = field(default_factory=list)  # per good client
    frame_times: list[list[float]] = field(default_factory=list)  # per good client
    latencies: list[tuple[float, float]] = field(default_factory=list)  # (time, ms)

    def fail(self, message: str) -> None:
        if len(self.failures) < 200:
            self.failures.append(f"{time.monotonic() - self.started:6.1f} s: {message}")
        self.counts["failures"] += 1

    def status(self, what: str, status: int) -> None:
        self.http_status[f"{what} {status}"] += 1
        if status >= 500:
            self.fail(f"{what}: server error {status}")


class Soak:
    def __init__(self, args: argparse.Namespace, port: int, demo: bytes) -> None:
        self.args = args
        self.base = f"http://127.0.0.1:{port}"
        self.ws = f"ws://127.0.0.1:{port}/v1/stream?asset=demo"
        self.port = port
        self.demo = demo
        self.stats = Stats()
        self.deadline = 0.0

    def running(self) -> bool:
        return time.monotonic() < self.deadline

    async def pause(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, min(seconds, self.deadline - time.monotonic())))

    # --- good clients ----------------------------------------------------------------------

    async def good_client(self, index: int) -> None:
        stats = self.stats
        stats.frames.append(0)
        stats.frame_times.append([])
        request = 0
        while self.running():
            try:
                async with connect(self.ws, max_size=8 * MIB, open_timeout=10) as ws:
                    hello = json.loads(await asyncio.wait_for(ws.recv(), 10))
                    if hello.get("type") != "hello":
                        stats.fail(f"good client {index}: first message {hello!r}")
                    while self.running():
                        request += 1
                        wait_full = request % 8 == 0
                        sent = time.monotonic()
                        await ws.send(json.dumps({
                            "type": "view", "id": request,
                            "view": orbit_view(0.05 * request + index)}))
                        await self.await_frame(ws, index, request, sent, wait_full)
            except (TimeoutError, OSError, websockets.exceptions.WebSocketException) as e:
                if self.running():
                    stats.fail(f"good client {index}: {type(e).__name__}: {e}")
                    await self.pause(1.0)

    async def await_frame(self, ws: ClientConnection, index: int, request: int, sent: float,
                          wait_full: bool) -> None:
        stats = self.stats
        first = True
        deadline = sent + FRAME_TIMEOUT_S
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                stats.fail(f"good client {index}: no frame for view {request} in "
                           f"{FRAME_TIMEOUT_S:.0f} s")
                return
            try:
                message = await asyncio.wait_for(ws.recv(), remaining)
            except TimeoutError:
                continue
            if isinstance(message, str):
                stats.fail(f"good client {index}: unexpected message {message[:200]}")
                continue
            (magic, header_len, _codec, quality, frame_id, request_id, *_rest) = \
                HEADER.unpack_from(message)
            if magic != b"LGF1" or header_len < HEADER.size:
                stats.fail(f"good client {index}: bad frame header {message[:16]!r}")
                return
            await ws.send(json.dumps({"type": "ack", "frame": frame_id}))
            now = time.monotonic()
            stats.frames[index] += 1
            stats.frame_times[index].append(now)
            if request_id != request:
                continue
            if first:
                stats.latencies.append((now, (now - sent) * 1000.0))
                first = False
            if not wait_full or quality == 1:
                return

    # --- abusive clients -------------------------------------------------------------------

    async def silent_client(self) -> None:
        """Sends one view, then nothing: holds its session until the idle limit closes it."""
        while self.running():
            try:
                async with connect(self.ws, max_size=8 * MIB, open_timeout=10) as ws:
                    await ws.recv()
                    await ws.send(json.dumps({"type": "view", "id": 1, "view": orbit_view(1.0)}))
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(ws.wait_closed(),
                                               self.deadline - time.monotonic())
                    if ws.close_code is not None:
                        self.stats.counts[f"silent closed {ws.close_code}"] += 1
            except (TimeoutError, OSError, websockets.exceptions.WebSocketException) as e:
                self.abuse_refused("silent", e)
                await self.pause(0.5)

    def abuse_refused(self, who: str, error: Exception) -> None:
        if isinstance(error, websockets.exceptions.InvalidStatus):
            self.stats.status(f"{who} upgrade", error.response.status_code)
        else:
            self.stats.counts[f"{who} {type(error).__name__}"] += 1

    async def oversized_client(self) -> None:
        """Messages over the 64 KiB limit: the server must close with 1009."""
        while self.running():
            try:
                async with connect(self.ws, max_size=8 * MIB, open_timeout=10) as ws:
                    await ws.recv()
                    await ws.send("x" * (100 * 1024))
                    with contextlib.suppress(websockets.exceptions.ConnectionClosed):
                        while True:
                            await asyncio.wait_for(ws.recv(), 10)
                code = ws.close_code
                self.stats.counts[f"oversized closed {code}"] += 1
                if code != 1009:
                    self.stats.fail(f"oversized message: close code {code}, expected 1009")
            except (TimeoutError, OSError, websockets.exceptions.WebSocketException) as e:
                self.abuse_refused("oversized", e)
            await self.pause(0.5)

    async def garbage_client(self) -> None:
        """Garbage on a session, which must stay open and then still answer a good view."""
        garbage: list[str | bytes] = [
            "not json", b"\x00\x01\x02binary", '{"type": "nope"}', '{"type": "view", "id": -1}',
            '{"type": "view", "id": 1, "view": {"eye": [0, 0, 0], "target": [0, 0, 0]}}',
            '{"type": "settings", "lod": "many"}', "[" * 5000, '{"type": "ack", "frame": 1e99}',
            "\u0000\ud7ff\ufffd", json.dumps({"type": "view", "id": 2, "view": orbit_view(
                0.0, width=100000, height=1)}),
        ]
        while self.running():
            try:
                async with connect(self.ws, max_size=8 * MIB, open_timeout=10) as ws:
                    await ws.recv()
                    for message in garbage:
                        await ws.send(message)
                    await ws.send(json.dumps({"type": "view", "id": 99,
                                              "view": orbit_view(2.0, 64, 48)}))
                    errors = 0
                    deadline = time.monotonic() + FRAME_TIMEOUT_S
                    while True:
                        reply = await asyncio.wait_for(ws.recv(), deadline - time.monotonic())
                        if isinstance(reply, str):
                            errors += 1
                            continue
                        frame = HEADER.unpack_from(reply)
                        if frame[5] == 99:
                            break
                    self.stats.counts["garbage sessions answered"] += 1
                    self.stats.counts["garbage error messages"] += errors
            except TimeoutError:
                self.stats.fail("garbage session: no frame for a good view after the garbage")
            except websockets.exceptions.ConnectionClosed as e:
                self.stats.fail(f"garbage session closed by the server: {e}")
            except (OSError, websockets.exceptions.WebSocketException) as e:
                self.abuse_refused("garbage", e)
            await self.pause(0.3)

    async def slow_loris(self, index: int) -> None:
        """A slow upload body (408 expected) or slow headers (connection closed)."""
        body_case = index % 2 == 0
        while self.running():
            try:
                reader, writer = await asyncio.open_connection("127.0.0.1", self.port)
            except OSError as e:
                self.stats.counts[f"slow-loris connect {type(e).__name__}"] += 1
                await self.pause(1.0)
                continue
            try:
                if body_case:
                    writer.write(f"POST /v1/assets?id=loris-{index} HTTP/1.1\r\nHost: soak\r\n"
                                 "Content-Type: application/octet-stream\r\n"
                                 "Content-Length: 1000000\r\n\r\nLFA".encode())
                else:
                    writer.write(b"GET /healthz HTTP/1.1\r\nHo")
                await writer.drain()
                answer = b""
                started = time.monotonic()
                while self.running() and time.monotonic() - started < 30:
                    try:
                        chunk = await asyncio.wait_for(reader.read(4096), 5.0)
                    except TimeoutError:
                        writer.write(b"x")  # one byte now and then, less often than the limit
                        await writer.drain()
                        continue
                    if not chunk:
                        break
                    answer += chunk
                    if b"\r\n\r\n" in answer:
                        break
                if not self.running():
                    continue
                if body_case:
                    status = int(answer.split(b" ", 2)[1]) if answer.startswith(b"HTTP/") else 0
                    self.stats.status("slow-loris body", status)
                    if status != 408:
                        self.stats.fail(f"slow-loris upload answered {status}, expected 408: "
                                        f"{answer[:200]!r}")
                else:
                    self.stats.counts["slow-loris headers closed"] += 1
                    if answer:
                        self.stats.fail(f"slow headers answered: {answer[:200]!r}")
            except (ConnectionResetError, BrokenPipeError):
                self.stats.counts["slow-loris reset"] += 1
            finally:
                writer.close()
                with contextlib.suppress(OSError):
                    await writer.wait_closed()

    async def churn_client(self) -> None:
        """Rapid connect/disconnect: WebSocket upgrades dropped at once, bare TCP connections."""
        n = 0
        while self.running():
            n += 1
            try:
                if n % 2:
                    ws = await connect(self.ws, open_timeout=10)
                    ws.transport.abort()
                    self.stats.counts["churn websocket"] += 1
                else:
                    _reader, writer = await asyncio.open_connection("127.0.0.1", self.port)
                    writer.close()
                    self.stats.counts["churn tcp"] += 1
            except (TimeoutError, OSError, websockets.exceptions.WebSocketException) as e:
                self.abuse_refused("churn", e)
            await asyncio.sleep(0.05)

    # --- uploads, deletes, bakes -----------------------------------------------------------

    async def expect(self, what: str, response: httpx.Response, status: int) -> bool:
        self.stats.status(what, response.status_code)
        if response.status_code != status:
            self.stats.fail(f"{what}: {response.status_code}, expected {status}: "
                            f"{response.text[:300]}")
            return False
        return True

    async def uploads(self, client: httpx.AsyncClient) -> None:
        n = 0
        while self.running():
            n += 1
            asset = f"soak-upload-{n}"
            try:
                response = await client.post(f"/v1/assets?id={asset}", content=self.demo)
                if await self.expect("upload", response, 201):
                    render = await client.post(f"/v1/assets/{asset}/render",
                                               json={"view": orbit_view(0.3 * n)})
                    await self.expect("render", render, 200)
                    await self.expect("delete", await client.delete(f"/v1/assets/{asset}"), 204)
            except httpx.HTTPError as e:
                self.stats.fail(f"upload cycle: {type(e).__name__}: {e}")
            await self.pause(2.0)

    async def bakes(self, client: httpx.AsyncClient) -> None:
        n = 0
        while self.running():
            n += 1
            asset = f"soak-bake-{n}"
            try:
                response = await client.post("/v1/bake", files={
                    "mesh": ("tetra.off", TETRA_OFF, "application/octet-stream")}, data={
                    "options": json.dumps({"cameras": 12, "resolution": 32}), "id": asset,
                    "calibrate": "false"})
                if await self.expect("bake", response, 202):
                    job = response.json()
                    deadline = time.monotonic() + 60
                    while job["state"] not in ("done", "failed") and time.monotonic() < deadline:
                        await asyncio.sleep(0.2)
                        poll = await client.get(f"/v1/jobs/{job['id']}")
                        self.stats.status("job", poll.status_code)
                        job = poll.json()
                    if job["state"] != "done":
                        self.stats.fail(f"bake job {job['id']}: {job}")
                    else:
                        self.stats.counts["bakes done"] += 1
                        await self.expect("delete baked", await client.delete(
                            f"/v1/assets/{asset}"), 204)
            except httpx.HTTPError as e:
                self.stats.fail(f"bake cycle: {type(e).__name__}: {e}")
            await self.pause(6.0)

    # --- the run ---------------------------------------------------------------------------

    async def sample(self, pid: int, samples: list[dict[str, Any]]) -> None:
        last_frames = [0] * self.args.good_clients
        last = time.monotonic()
        while self.running():
            await asyncio.sleep(1.0)
            now = time.monotonic()
            rss = rss_bytes(pid)
            if rss is None:
                self.stats.fail("the server process is gone")
                self.deadline = now
                return
            frames = list(self.stats.frames) + [0] * (len(last_frames) - len(self.stats.frames))
            fps = [(f - g) / (now - last) for f, g in zip(frames, last_frames, strict=True)]
            window = [ms for t, ms in self.stats.latencies if last < t <= now]
            samples.append({
                "t": round(now - self.stats.started, 2), "rss_mib": round(rss / MIB, 1),
                "fps": round(statistics.fmean(fps), 2) if fps else 0.0,
                "p50_ms": rounded(percentile(window, 0.5)),
                "p95_ms": rounded(percentile(window, 0.95)),
            })
            last_frames, last = frames, now

    async def run(self, pid: int) -> list[dict[str, Any]]:
        self.stats.started = time.monotonic()
        self.deadline = self.stats.started + self.args.seconds
        samples: list[dict[str, Any]] = []
        async with httpx.AsyncClient(base_url=self.base, timeout=60) as client:
            tasks = [self.sample(pid, samples), self.uploads(client), self.bakes(client)]
            tasks += [self.good_client(i) for i in range(self.args.good_clients)]
            tasks += [self.silent_client() for _ in range(4)]
            tasks += [self.oversized_client(), self.garbage_client(), self.churn_client()]
            tasks += [self.slow_loris(i) for i in range(4)]
            await asyncio.gather(*tasks)
        return samples


def rss_verdict(samples: list[dict[str, Any]], pct: float, mib: float) -> dict[str, Any]:
    """Compares the largest RSS of the last third with the second's (see the module doc)."""
    n = len(samples)
    third = n // 3
    mid = [s["rss_mib"] for s in samples[third:2 * third]]
    end = [s["rss_mib"] for s in samples[2 * third:]]
    if not mid or not end:
        return {"flat": False, "reason": f"only {n} samples"}
    mid_max, end_max = max(mid), max(end)
    allowed = max(mid_max * pct / 100.0, mib)
    growth = end_max - mid_max
    return {"flat": growth <= allowed, "mid_max_mib": mid_max, "end_max_mib": end_max,
            "growth_mib": round(growth, 1), "allowed_mib": round(allowed, 1)}


def plot(samples: list[dict[str, Any]], path: Path) -> str:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "matplotlib is not installed: no plot"
    t = [s["t"] for s in samples]
    fig, (ax_rss, ax_fps) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax_rss.plot(t, [s["rss_mib"] for s in samples], color="tab:blue")
    ax_rss.set_ylabel("server RSS (MiB)")
    ax_rss.grid(alpha=0.3)
    ax_fps.plot(t, [s["fps"] for s in samples], color="tab:green", label="fps per good client")
    ax_fps.set_ylabel("fps")
    ax_fps.set_xlabel("seconds")
    ax_fps.grid(alpha=0.3)
    ax_lat = ax_fps.twinx()
    for key, style in (("p50_ms", "-"), ("p95_ms", "--")):
        ax_lat.plot(t, [s[key] if s[key] is not None else math.nan for s in samples],
                    style, color="tab:red", label=f"latency {key[:3]}")
    ax_lat.set_ylabel("view → frame latency (ms)")
    fig.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def start_server(binary: Path, tmp: Path) -> tuple[subprocess.Popen[bytes], int, bytes, Path]:
    env = dict(os.environ)
    env.pop("LUMIGRAPH_TOKEN", None)
    runtime = env.get("XDG_RUNTIME_DIR")
    if not runtime or not os.path.isdir(runtime):
        runtime = str(tmp / "xdg")
        os.mkdir(runtime, 0o700)
        env["XDG_RUNTIME_DIR"] = runtime
    assets = tmp / "assets"
    assets.mkdir()
    demo = tmp / "demo.lfa"
    baked = subprocess.run([str(binary), "bake", "--demo", "-o", str(demo), "--cameras", "12",
                            "--resolution", "64"], capture_output=True, text=True, env=env,
                           timeout=120, check=False)
    if baked.returncode != 0:
        raise SystemExit(f"demo bake failed:\n{baked.stdout}\n{baked.stderr}")
    shutil.copyfile(demo, assets / "demo.lfa")
    port = free_port()
    log = (tmp / "server.log").open("wb")
    proc = subprocess.Popen(
        [str(binary), "serve", "--assets", str(assets), "--addr", f"127.0.0.1:{port}",
         "--max-px", "512", "--stream-idle-secs", "8", "--body-timeout-secs", "4",
         "--header-timeout-secs", "4"],
        stdout=log, stderr=subprocess.STDOUT, env=env)
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"server exited with {proc.returncode} before ready:\n"
                             f"{(tmp / 'server.log').read_text(errors='replace')[-4000:]}")
        with contextlib.suppress(httpx.TransportError):
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200:
                return proc, port, demo.read_bytes(), tmp / "server.log"
        time.sleep(0.1)
    proc.kill()
    raise SystemExit("server not ready after 90 s")


def internal_errors(port: int) -> float:
    text = httpx.get(f"http://127.0.0.1:{port}/metrics", timeout=10).text
    total = 0.0
    for line in text.splitlines():
        if line.startswith("lumigraph_errors_total{") and 'kind="internal"' in line:
            total += float(line.rpartition(" ")[2])
    return total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the run")
    parser.add_argument("--out", type=Path, default=ROOT / "target" / "soak",
                        help="folder for soak.json and soak.png")
    parser.add_argument("--bin", type=Path, default=default_binary(), help="lumigraph binary")
    parser.add_argument("--good-clients", type=int, default=3)
    parser.add_argument("--rss-tolerance-pct", type=float, default=10.0)
    parser.add_argument("--rss-tolerance-mib", type=float, default=16.0)
    args = parser.parse_args()
    if not args.bin.is_file():
        print(f"{args.bin} is missing: build it with cargo build --release -p lumigraph_server",
              file=sys.stderr)
        return 2
    if args.seconds < 9:
        print("--seconds must be at least 9 (three thirds of three samples)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="lumigraph-soak-") as tmp_name:
        tmp = Path(tmp_name)
        proc, port, demo, log_path = start_server(args.bin, tmp)
        soak = Soak(args, port, demo)
        try:
            samples = asyncio.run(soak.run(proc.pid))
            stats = soak.stats
            if proc.poll() is None:
                internal = internal_errors(port)
                if internal:
                    stats.fail(f"lumigraph_errors_total{{kind=\"internal\"}} = {internal:g}")
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
                    soak.stats.fail("the server ignored SIGTERM for 20 s")
            log = log_path.read_text(errors="replace")
            shutil.copyfile(log_path, args.out / "server.log")
        if proc.returncode != 0:
            stats.fail(f"the server exited with {proc.returncode}")
        if "panicked" in log:
            stats.fail("the server log shows a panic")
    summary = summarize(args, samples, stats)
    report = {"parameters": {k: str(v) for k, v in vars(args).items()}, "summary": summary,
              "counts": dict(stats.counts), "http_status": dict(stats.http_status),
              "failures": stats.failures, "samples": samples}
    (args.out / "soak.json").write_text(json.dumps(report, indent=1))
    summary["plot"] = plot(samples, args.out / "soak.png") if samples else "no samples"
    print_summary(summary, stats, args.out)
    return 1 if stats.failures else 0


def summarize(args: argparse.Namespace, samples: list[dict[str, Any]], stats: Stats
              ) -> dict[str, Any]:
    rss = rss_verdict(samples, args.rss_tolerance_pct, args.rss_tolerance_mib)
    if not rss["flat"]:
        stats.fail(f"RSS not flat after warm-up: {rss}")
    start, end = stats.started, stats.started + args.seconds
    thirds = [(start + i * (end - start) / 3, start + (i + 1) * (end - start) / 3)
              for i in range(3)]
    for index, times in enumerate(stats.frame_times):
        for number, (a, b) in enumerate(thirds, 1):
            if not any(a <= t < b for t in times):
                stats.fail(f"good client {index} got no frame in third {number} of the run")
    latencies = [ms for _t, ms in stats.latencies]
    fps = [s["fps"] for s in samples]
    return {
        "seconds": args.seconds,
        "rss_start_mib": samples[0]["rss_mib"] if samples else None,
        "rss_end_mib": samples[-1]["rss_mib"] if samples else None,
        "rss_max_mib": max((s["rss_mib"] for s in samples), default=None),
        "rss": rss,
        "frames": sum(stats.frames),
        "fps_per_client_mean": round(statistics.fmean(fps), 2) if fps else 0.0,
        "latency_p50_ms": rounded(percentile(latencies, 0.5)),
        "latency_p95_ms": rounded(percentile(latencies, 0.95)),
        "views_answered": len(latencies),
    }


def print_summary(summary: dict[str, Any], stats: Stats, out: Path) -> None:
    def ms(value: float | None) -> str:
        return "-" if value is None else f"{value:.0f} ms"

    rss = summary["rss"]
    print(f"soak: {summary['seconds']:.0f} s; RSS start {summary['rss_start_mib']} MiB, "
          f"end {summary['rss_end_mib']} MiB, max {summary['rss_max_mib']} MiB; "
          f"second-third max {rss.get('mid_max_mib')} MiB, last-third max "
          f"{rss.get('end_max_mib')} MiB (growth {rss.get('growth_mib')}, allowed "
          f"{rss.get('allowed_mib')} MiB): {'flat' if rss['flat'] else 'NOT FLAT'}")
    print(f"soak: good clients: {summary['frames']} frames, "
          f"{summary['fps_per_client_mean']} fps per client, view→frame latency p50 "
          f"{ms(summary['latency_p50_ms'])}, p95 {ms(summary['latency_p95_ms'])} over "
          f"{summary['views_answered']} views")
    print("soak: " + ", ".join(f"{k}: {v}" for k, v in sorted(stats.counts.items())))
    print("soak: HTTP " + ", ".join(f"{k}: {v}" for k, v in sorted(stats.http_status.items())))
    print(f"soak: report {out / 'soak.json'}; plot: {summary['plot']}")
    if stats.failures:
        print(f"soak FAILED ({stats.counts['failures']} failures):", file=sys.stderr)
        for failure in stats.failures[:40]:
            print(f"  {failure}", file=sys.stderr)
    else:
        print("soak passed")


if __name__ == "__main__":
    sys.exit(main())
