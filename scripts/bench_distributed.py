"""Batch-bake throughput: lumigraph.distributed.bake_many against one process baking in a loop.

    .venv/bin/python scripts/bench_distributed.py [--out out/distributed-bench] [--cameras 162]
        [--resolution 512]

(`bash scripts/bench_distributed.sh` builds the extension into .venv with Ray from
pylib/requirements-test.txt and runs this). Sources: the dev fixture meshes (bunny, cow, spot) and five
generated shapes, eight meshes. Configurations, each into an empty folder:

- one process: `bake_mesh` + `save` in a loop in this process (lavapipe's default threads);
- local engine, 2 workers x 1 thread and 1 worker x 2 threads;
- Ray: a one-node cluster on loopback (`ray start --head`, 2 CPUs), 1 thread per task, started
  before the clock and stopped after.

The time of a bake_many configuration includes its worker start-up (process spawn, device
creation) but not the Ray cluster's. Writes OUT/results.json and OUT/table.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import trimesh

import lumigraph as lg
from lumigraph.distributed import bake_many

ROOT = Path(__file__).resolve().parents[1]


def sources(folder: Path) -> list[Path]:
    fixtures = Path(os.environ.get("LUMIGRAPH_FIXTURES") or ROOT / "fixtures") / "mesh"
    paths = [fixtures / name for name in ("bunny00.off", "cow.off", "spot.ply")]
    missing = [p for p in paths if not p.exists()]
    if missing:
        sys.exit(f"missing fixtures {missing}: run bash scripts/fixtures.sh")
    folder.mkdir(parents=True, exist_ok=True)
    shapes = {
        "icosphere.ply": trimesh.creation.icosphere(subdivisions=4),
        "torus.ply": trimesh.creation.torus(major_radius=1.0, minor_radius=0.3),
        "capsule.obj": trimesh.creation.capsule(height=1.0, radius=0.4),
        "cylinder.stl": trimesh.creation.cylinder(radius=0.5, height=1.2, sections=64),
        "box.stl": trimesh.creation.box(extents=(1.0, 0.5, 0.8)),
    }
    for name, mesh in shapes.items():
        mesh.export(folder / name)
        paths.append(folder / name)
    return paths


def one_process(paths: list[Path], out: Path, options: dict[str, Any]) -> float:
    out.mkdir(parents=True)
    start = time.perf_counter()
    for path in paths:
        lg.bake_mesh(lg.Mesh.load(path), progress=False, **options).save(out / f"{path.stem}.lfa")
    return time.perf_counter() - start


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def ray_head(temp: str, port: int) -> subprocess.Popen[bytes]:
    ray_cli = Path(sys.executable).parent / "ray"
    head = subprocess.Popen(
        [str(ray_cli), "start", "--head", "--block", "--node-ip-address", "127.0.0.1", "--port", str(port),
         "--num-cpus", "2", "--include-dashboard=false", "--disable-usage-stats", "--temp-dir", temp,
         "--object-store-memory", str(200 * 2**20)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while subprocess.run([str(ray_cli), "status", "--address", f"127.0.0.1:{port}"],
                         capture_output=True, check=False).returncode != 0:  # fmt: skip
        if head.poll() is not None or time.monotonic() > deadline:
            sys.exit("ray did not start")
        time.sleep(1)
    return head


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "distributed-bench")
    parser.add_argument("--cameras", type=int, default=162)
    parser.add_argument("--resolution", type=int, default=512)
    args = parser.parse_args()
    if args.out.exists():
        shutil.rmtree(args.out)
    paths = sources(args.out / "meshes")
    options = {"cameras": args.cameras, "resolution": args.resolution}
    rows: list[dict[str, Any]] = []

    def record(name: str, seconds: float, baked: int, failed: int = 0) -> None:
        rows.append({"configuration": name, "seconds": round(seconds, 2), "baked": baked, "failed": failed,
                     "bakes_per_minute": round(60 * baked / seconds, 2)})  # fmt: skip
        print(f"{name}: {baked} in {seconds:.1f} s = {60 * baked / seconds:.1f} bakes/min", file=sys.stderr)

    record("one process, loop", one_process(paths, args.out / "one", options), len(paths))
    for workers, threads in [(2, 1), (1, 2)]:
        report = bake_many(paths, out=args.out / f"local-{workers}x{threads}", engine="local", workers=workers,
                           threads_per_worker=threads, progress=False, **options)  # fmt: skip
        record(f"local engine, {workers} workers x {threads} threads", report.seconds, len(report.baked),
               len(report.failed))  # fmt: skip
    temp = tempfile.mkdtemp(prefix="lgray", dir="/tmp")
    port = free_port()
    head = ray_head(temp, port)
    try:
        report = bake_many(paths, out=args.out / "ray", engine="ray", address=f"127.0.0.1:{port}",
                           threads_per_worker=1, progress=False, **options)  # fmt: skip
        record("Ray, one-node cluster of 2 CPUs, 1 thread per task", report.seconds, len(report.baked),
               len(report.failed))  # fmt: skip
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        head.wait(timeout=60)
        shutil.rmtree(temp, ignore_errors=True)

    machine = f"{platform.machine()}, {os.cpu_count()} CPUs, {lg.device_info()}"
    result = {"machine": machine, "options": options, "meshes": [p.name for p in paths], "rows": rows}
    (args.out / "results.json").write_text(json.dumps(result, indent=2) + "\n")
    base = rows[0]["bakes_per_minute"]
    lines = [
        f"{len(paths)} meshes ({', '.join(p.name for p in paths)}), {args.cameras} cameras x "
        f"{args.resolution} px; {machine}",
        "",
        "| configuration | wall s | baked | bakes/min | vs one process |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['configuration']} | {r['seconds']} | {r['baked']} | {r['bakes_per_minute']} | "
        f"{r['bakes_per_minute'] / base:.2f}x |"
        for r in rows
    ]
    (args.out / "table.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
