#!/usr/bin/env python3
"""Stream throughput of several replicas behind the router against one replica (a benchmark).

Bakes the demo once (162 cameras, 256 px maps), copies it as four assets (scene0..scene3) into
every replica's folder, then runs CLIENTS closed-loop stream clients (a still 512x512 JPEG view,
its frame, ack, the next view), spread evenly over the four assets, for SECONDS each against:

- one replica, directly;
- one replica behind HAProxy (the router's cost);
- three replicas behind HAProxy with docker/k8s/router.yaml's balancing (consistent hashing on
  `asset`, bounded load).

Needs the release binary (target/release/lumigraph or $LUMIGRAPH_BIN), haproxy, and httpx +
websockets (scripts/bench_replicas.sh makes the venv). Writes a markdown report:
`PY scripts/bench_replicas.py [--out out/bench_replicas.md] [--clients 16] [--seconds 15]`.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_service import Client, closed_loops, finish_report, free_port, pct, start_server  # noqa: E402

ASSETS = [f"scene{i}" for i in range(4)]


def haproxy_config(port: int, ports: list[int]) -> str:
    lines = [
        "global", "    maxconn 4000",
        "defaults", "    mode http", "    timeout connect 2s", "    timeout client 60s",
        "    timeout server 60s", "    timeout tunnel 10m", "    retries 3", "    option redispatch",
        "frontend http", f"    bind 127.0.0.1:{port}", "    default_backend replicas",
        "backend replicas", "    balance url_param asset", "    hash-type consistent",
        "    hash-balance-factor 150", "    option httpchk GET /readyz",
        "    default-server check inter 1s fall 2 rise 2",
    ]  # fmt: skip
    lines += [f"    server r{i} 127.0.0.1:{p}" for i, p in enumerate(ports)]
    return "\n".join(lines) + "\n"


async def load(base: str, clients: int, seconds: float) -> dict[str, Any]:
    ws = base.replace("http", "ws", 1)
    conns = [
        await Client.open(f"{ws}/v1/stream?asset={ASSETS[i % len(ASSETS)]}",
                          {"interactive": False, "still_codec": "jpeg"})
        for i in range(clients)
    ]  # fmt: skip
    latencies, _, fps = await closed_loops(conns, seconds, warm_s=2.0)
    return {"frames": len(latencies), "fps_total": sum(fps), "fps_min": min(fps),
            "p50": pct(latencies, 0.5), "p95": pct(latencies, 0.95)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/bench_replicas.md"))
    parser.add_argument("--clients", type=int, default=16)
    parser.add_argument("--seconds", type=float, default=15.0)
    args = parser.parse_args()
    haproxy = shutil.which("haproxy") or "/usr/sbin/haproxy"
    rows: list[tuple[str, dict[str, Any]]] = []
    codes: list[int] = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        # The demo, baked once by a first server, becomes the four assets of every replica.
        seed_port = free_port()
        seed = start_server(tmp / "seed", seed_port, tmp / "seed.log")
        seed.send_signal(signal.SIGTERM)
        codes.append(seed.wait(timeout=30))
        folders = []
        for index in range(3):
            folder = tmp / f"replica{index}"
            folder.mkdir()
            for name in ASSETS:
                shutil.copyfile(tmp / "seed" / "demo.lfa", folder / f"{name}.lfa")
            folders.append(folder)

        def run(name: str, replicas: int, router: bool) -> None:
            ports = [free_port() for _ in range(replicas)]
            procs = [start_server(folders[i], ports[i], tmp / f"{name}-{i}.log") for i in range(replicas)]
            proxy = None
            try:
                base = f"http://127.0.0.1:{ports[0]}"
                if router:
                    port = free_port()
                    config = tmp / "haproxy.cfg"
                    config.write_text(haproxy_config(port, ports))
                    proxy = subprocess.Popen([haproxy, "-db", "-f", str(config)], stdout=subprocess.DEVNULL,
                                             stderr=subprocess.DEVNULL)  # fmt: skip
                    base = f"http://127.0.0.1:{port}"
                    time.sleep(3)  # every server's health check passed (rise 2 x 1 s)
                    httpx.get(f"{base}/readyz?asset=x", timeout=5).raise_for_status()
                rows.append((name, asyncio.run(load(base, args.clients, args.seconds))))
                print(f"{name}: {rows[-1][1]}", file=sys.stderr)
            finally:
                if proxy is not None:
                    proxy.terminate()
                    proxy.wait(timeout=10)
                for proc in procs:
                    proc.send_signal(signal.SIGTERM)
                    codes.append(proc.wait(timeout=30))

        run("one replica, direct", 1, False)
        run("one replica behind HAProxy", 1, True)
        run("three replicas behind HAProxy", 3, True)

    base_fps = rows[0][1]["fps_total"]
    lines = [
        "## Replicas behind the router (scripts/bench_replicas.py)",
        "",
        f"Machine: {os.cpu_count()} CPU cores, {platform.machine()}. {args.clients} closed-loop stream "
        f"clients (512x512 JPEG stills) over {len(ASSETS)} copies of the demo asset, "
        f"{args.seconds:.0f} s measured after 2 s of warm-up, every replica and HAProxy on this machine.",
        "",
        "| configuration | frames | total fps | vs one replica | slowest client fps | latency p50 ms | p95 ms |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in rows:
        lines.append(
            f"| {name} | {r['frames']} | {r['fps_total']:.1f} | {r['fps_total'] / base_fps:.2f}x | "
            f"{r['fps_min']:.2f} | {r['p50']:.0f} | {r['p95']:.0f} |"
        )
    lines.append("")
    finish_report(args.out, lines, max(codes, key=abs))


if __name__ == "__main__":
    main()
