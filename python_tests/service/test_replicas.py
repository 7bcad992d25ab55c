"""Many replicas behind a router, as docker/k8s/router.yaml deploys them: three `lumigraph serve`
processes on loopback behind HAProxy (Debian's package) with the router's balancing (consistent
hashing on the `asset` query parameter, bounded load, /readyz health checks, redispatch).
Sessions of one asset stick to one replica; when that replica gets SIGTERM mid-stream its
clients reconnect through the router, re-send view and settings (as the web viewer does), land on
another replica and get the same frames."""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import struct
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from conftest import Server, free_port

HEADER = struct.Struct("<4sHBBIIIIffIHBB")
VIEW = {"eye": [0.4, 0.8, 3.2], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40,
        "width": 96, "height": 80}
SETTINGS = {"type": "settings", "interactive": False, "still_codec": "png"}
ASSETS = [f"scene{i}" for i in range(6)]
CLIENTS = 4


def haproxy_config(port: int, servers: list[Server]) -> str:
    """The router's configuration (docker/k8s/router.yaml) with static servers instead of the
    cluster's DNS template, and the replica's name in a response header for the test."""
    lines = [
        "global", "    maxconn 2000",
        "defaults", "    mode http", "    timeout connect 2s", "    timeout client 60s",
        "    timeout server 60s", "    timeout tunnel 10m", "    timeout http-request 10s",
        "    retries 3", "    option redispatch",
        "frontend http", f"    bind 127.0.0.1:{port}", "    default_backend replicas",
        "backend replicas", "    balance url_param asset", "    hash-type consistent",
        "    hash-balance-factor 150", "    option httpchk GET /readyz",
        "    http-check expect status 200", "    http-response set-header X-Replica %s",
        "    default-server check inter 500ms fall 2 rise 2",
    ]  # fmt: skip
    lines += [f"    server r{i} 127.0.0.1:{s.port}" for i, s in enumerate(servers)]
    return "\n".join(lines) + "\n"


@pytest.fixture
def cluster(tmp_path: Path, demo_lfa: Path) -> Iterator[tuple[str, list[Server]]]:
    haproxy = shutil.which("haproxy") or "/usr/sbin/haproxy"
    if not Path(haproxy).exists():
        pytest.fail("haproxy is missing: scripts/test_service_e2e.sh installs it (apt-get install haproxy)")
    servers: list[Server] = []
    proc = None
    try:
        for i in range(3):
            assets = tmp_path / f"replica{i}"
            assets.mkdir()
            for name in ASSETS:  # every replica reads the same assets (a shared store)
                shutil.copyfile(demo_lfa, assets / f"{name}.lfa")
            servers.append(Server(assets, tmp_path / f"replica{i}.log", None, []))
        for server in servers:
            server.wait_ready()
        port = free_port()
        config = tmp_path / "haproxy.cfg"
        config.write_text(haproxy_config(port, servers))
        check = subprocess.run([haproxy, "-c", "-f", str(config)], capture_output=True, text=True)
        assert check.returncode == 0, check.stdout + check.stderr
        proc = subprocess.Popen([haproxy, "-db", "-f", str(config)], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)  # fmt: skip
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 30
        while True:
            with contextlib.suppress(httpx.TransportError):
                if httpx.get(f"{base}/readyz?asset=x", timeout=2).status_code == 200:
                    break
            assert proc.poll() is None and time.monotonic() < deadline, "haproxy did not come up"
            time.sleep(0.2)
        time.sleep(1.5)  # every server's health check has passed (rise 2 × 500 ms)
        yield base, servers
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(timeout=10)
        for server in servers:
            server.stop()


async def still(ws: Any, request_id: int) -> bytes:
    await ws.send(json.dumps(SETTINGS))
    await ws.send(json.dumps({"type": "view", "id": request_id, "view": VIEW, "still": True}))
    while True:
        message = await asyncio.wait_for(ws.recv(), 30)
        assert isinstance(message, bytes), message
        fields = HEADER.unpack_from(message)
        if fields[5] == request_id:
            return bytes(message[fields[1]:])


class Viewer:
    """A stream client that behaves like the web viewer: it keeps its session open, and when the
    server closes it waits 1.5 s, reconnects through the router and re-sends its settings and
    view. `replicas[i]` served `frames[i]`."""

    def __init__(self, base: str, asset: str) -> None:
        self.url = base.replace("http", "ws", 1) + f"/v1/stream?asset={asset}"
        self.replicas: list[str] = []
        self.frames: list[bytes] = []
        self.first = asyncio.Event()
        self.done = asyncio.Event()

    async def run(self, frames: int) -> None:
        """Until `frames` frames arrived (one per session) or `done` is set."""
        while len(self.frames) < frames and not self.done.is_set():
            with contextlib.suppress(ConnectionClosed, OSError, asyncio.TimeoutError):
                async with connect(self.url, max_size=1 << 24, open_timeout=5) as ws:
                    assert ws.response is not None
                    replica = ws.response.headers.get("X-Replica", "?")
                    assert json.loads(await ws.recv())["type"] == "hello"
                    png = await still(ws, len(self.frames) + 1)
                    self.replicas.append(replica)
                    self.frames.append(png)
                    self.first.set()
                    if len(self.frames) >= frames:
                        return
                    # Open until the server closes the session or the test is done with it.
                    closed = asyncio.ensure_future(ws.wait_closed())
                    finished = asyncio.ensure_future(self.done.wait())
                    await asyncio.wait([closed, finished], return_when=asyncio.FIRST_COMPLETED)
                    closed.cancel()
                    finished.cancel()
                    if self.done.is_set():
                        return
            await asyncio.sleep(1.5)


def test_sessions_stick_to_a_replica_per_asset(cluster: tuple[str, list[Server]]) -> None:
    base, _ = cluster

    async def body() -> dict[str, set[str]]:
        seen: dict[str, set[str]] = {}
        for asset in ASSETS:
            for _ in range(3):  # one after another: bounded load spreads only concurrent sessions
                viewer = Viewer(base, asset)
                await viewer.run(1)
                seen.setdefault(asset, set()).update(viewer.replicas)
                # The router releases the closed session's server connection (it still counts
                # towards the bounded load for a moment).
                await asyncio.sleep(0.3)
        return seen

    seen = asyncio.run(asyncio.wait_for(body(), 120))
    assert all(len(replicas) == 1 for replicas in seen.values()), seen
    # Six assets over three replicas: consistent hashing uses more than one of them.
    assert len(set().union(*seen.values())) >= 2, seen


def test_clients_of_a_lost_replica_reconnect_elsewhere_and_get_the_same_frames(
    cluster: tuple[str, list[Server]],
) -> None:
    """Four viewers of one asset (bounded load may spread them over replicas); the replica of
    the first one gets SIGTERM: every viewer it served reconnects to a surviving replica and gets
    the same frame as before, bit for bit; the others keep their sessions."""
    base, servers = cluster

    async def body() -> tuple[list[Viewer], str]:
        viewers = [Viewer(base, ASSETS[0]) for _ in range(CLIENTS)]
        tasks = [asyncio.create_task(v.run(2)) for v in viewers]
        await asyncio.wait_for(asyncio.gather(*(v.first.wait() for v in viewers)), 60)
        victim_name = viewers[0].replicas[0]
        victim = servers[int(victim_name.removeprefix("r"))]
        code = await asyncio.to_thread(victim.stop)
        assert code == 0, victim.log_tail()
        moved = [v for v in viewers if v.replicas[0] == victim_name]
        await asyncio.wait_for(asyncio.gather(*(t for v, t in zip(viewers, tasks, strict=True) if v in moved)), 60)
        for v in viewers:
            v.done.set()
        await asyncio.wait_for(asyncio.gather(*tasks), 30)
        return moved, victim_name

    moved, victim_name = asyncio.run(asyncio.wait_for(body(), 150))
    assert moved, "the first viewer's replica served it"
    for v in moved:
        assert len(v.frames) == 2 and v.replicas[1] != victim_name, v.replicas
        assert v.frames[1] == v.frames[0], "the replica that took over rendered a different frame"
    # The survivors still answer through the router.
    assert httpx.get(f"{base}/readyz?asset={ASSETS[0]}", timeout=5).status_code == 200
