"""lumigraph.distributed.bake_many: batch baking in local worker processes and on a real local Ray
cluster (`ray start --head` on 127.0.0.1, stopped after), content-addressed idempotent outputs,
a failure report per source, options checked before any work."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import trimesh

import lumigraph as lg
from lumigraph.distributed import BakeResult, asset_name, bake_many

OPTIONS = {"cameras": 12, "resolution": 32}
VIEW = {
    "eye": [0.4, 0.5, 3.0],
    "target": [0, 0, 0],
    "up": [0, 1, 0],
    "yfov_deg": 40,
    "width": 48,
    "height": 40,
}


@pytest.fixture(scope="module")
def meshes(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three small meshes in three formats (the worker loads each from its file)."""
    folder = tmp_path_factory.mktemp("meshes")
    shapes = [
        ("sphere.ply", trimesh.creation.icosphere(subdivisions=2)),
        ("box.stl", trimesh.creation.box(extents=(1.0, 0.6, 0.8))),
        ("capsule.obj", trimesh.creation.capsule(height=0.8, radius=0.3)),
    ]
    paths = []
    for name, mesh in shapes:
        mesh.export(folder / name)
        paths.append(folder / name)
    return paths


@pytest.fixture(scope="module")
def bad_sources(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    folder = tmp_path_factory.mktemp("bad")
    (folder / "garbage.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999\nend_header\n"
    )
    return [folder / "garbage.ply", folder / "missing.obj"]


def frame_of(asset: Path) -> np.ndarray:
    return lg.LightField.open(str(asset)).render(VIEW).color


def test_local_engine_bakes_skips_and_reports_failures(
    meshes: list[Path], bad_sources: list[Path], tmp_path: Path
) -> None:
    seen: list[BakeResult] = []
    report = bake_many(
        [*meshes, *bad_sources],
        out=tmp_path / "out",
        engine="local",
        workers=2,
        progress=False,
        on_result=seen.append,
        **OPTIONS,
    )
    assert [r.source for r in report.results] == [str(p) for p in [*meshes, *bad_sources]]
    assert len(seen) == 5 and report.workers == 2 and report.threads_per_worker == 1
    assert [r.status for r in report.results] == ["baked"] * 3 + ["failed"] * 2
    # Two worker processes, none of them this one: each owns its device.
    assert {r.worker for r in report.baked} <= {r.worker for r in report.results if r.worker}
    assert os.getpid() not in {r.worker for r in report.results}

    garbage, missing = report.failed
    assert garbage.asset is None and missing.asset is None
    assert garbage.error is not None and garbage.error.startswith("MeshError"), garbage.error
    assert (
        missing.error is not None
        and "cannot read the source" in missing.error
        and "missing.obj" in missing.error
    )
    summary = report.summary()
    assert summary.startswith("3 baked, 0 skipped, 2 failed")
    assert f"FAILED {garbage.source}: MeshError" in summary and f"FAILED {missing.source}" in summary

    for mesh, result in zip(meshes, report.baked, strict=True):
        assert result.asset == tmp_path / "out" / asset_name(mesh, OPTIONS)
        assert result.seconds > 0
        lf = lg.LightField.open(str(result.asset))
        assert (lf.cameras, lf.resolution) == (12, 32)
        # The worker's bake is the same as one in this process (the bake is deterministic:
        # identical colour bytes, tolerance 0).
        here = lg.bake_mesh(lg.Mesh.load(mesh), progress=False, **OPTIONS).render(VIEW).color
        np.testing.assert_array_equal(frame_of(result.asset), here, err_msg=str(mesh))
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(
        r.asset.name for r in report.baked if r.asset
    )

    # Idempotent: a second run skips every asset and rewrites none; failures are reported again.
    stamps = {r.asset: r.asset.stat().st_mtime_ns for r in report.baked if r.asset}
    again = bake_many(
        [*meshes, *bad_sources], out=tmp_path / "out", engine="local", progress=False, **OPTIONS
    )
    assert [r.status for r in again.results] == ["skipped"] * 3 + ["failed"] * 2
    assert {r.asset: r.asset.stat().st_mtime_ns for r in again.skipped if r.asset} == stamps
    assert again.bakes_per_minute == 0.0

    # Other options, other names: nothing is skipped.
    other = bake_many(
        meshes[:1], out=tmp_path / "out", engine="local", progress=False, cameras=12, resolution=24
    )
    assert [r.status for r in other.results] == ["baked"]
    assert other.results[0].asset is not None and other.results[0].asset not in stamps


def test_asset_names_follow_content_options_and_not_the_folder(meshes: list[Path], tmp_path: Path) -> None:
    copy = tmp_path / meshes[0].name
    copy.write_bytes(meshes[0].read_bytes())
    name = asset_name(meshes[0], OPTIONS)
    assert name == asset_name(copy, dict(reversed(list(OPTIONS.items()))))
    assert name.startswith("sphere-") and name.endswith(".lfa") and len(name) == len("sphere-") + 16 + 4
    assert name != asset_name(meshes[0], {**OPTIONS, "resolution": 33})
    copy.write_bytes(meshes[0].read_bytes() + b"\n")
    assert name != asset_name(copy, OPTIONS)


@pytest.mark.parametrize(("kwargs", "error", "text"), [
    ({"engine": "spark"}, ValueError, "engine must be 'local' or 'ray'"),
    ({"workers": 0}, ValueError, "workers must be an integer >= 1"),
    ({"threads_per_worker": 0}, ValueError, "threads_per_worker must be an integer >= 1"),
    ({"threads_per_worker": True}, ValueError, "threads_per_worker must be an integer >= 1"),
    ({"address": "127.0.0.1:1"}, ValueError, "address is for engine='ray'"),
    ({"camera": 12}, TypeError, "unknown bake option(s) camera"),
    ({"light": object()}, TypeError, "not a plain JSON value"),
    ({"ambient": float("nan")}, TypeError, "not a plain JSON value"),
])  # fmt: skip
def test_bad_arguments_fail_before_any_work(
    meshes: list[Path], tmp_path: Path, kwargs: dict[str, object], error: type[Exception], text: str
) -> None:
    with pytest.raises(error) as raised:
        bake_many(meshes, out=tmp_path / "out", **kwargs)  # type: ignore[arg-type]
    assert text in str(raised.value)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_a_source_given_twice_is_refused(meshes: list[Path], tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="is given twice"):
        bake_many([meshes[0], meshes[0].parent / ".." / meshes[0].parent.name / meshes[0].name], out=tmp_path)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[str]:
    """A real one-node Ray cluster on loopback, started with `ray start --head --block` and
    stopped by SIGTERM after the module's tests."""
    ray_cli = Path(sys.executable).parent / "ray"
    port = free_port()
    temp = tempfile.mkdtemp(prefix="lgray", dir="/tmp")  # Ray's socket paths must stay short
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    log = Path(temp) / "head.log"
    with open(log, "wb") as log_file:
        head = subprocess.Popen(
            [
                str(ray_cli),
                "start",
                "--head",
                "--block",
                "--node-ip-address",
                "127.0.0.1",
                "--port",
                str(port),
                "--num-cpus",
                "2",
                "--include-dashboard=false",
                "--disable-usage-stats",
                "--temp-dir",
                temp,
                "--object-store-memory",
                str(200 * 2**20),
            ],
            env=env,
            stdout=log_file,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    address = f"127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            probe = subprocess.run(
                [str(ray_cli), "status", "--address", address],
                env=env,
                capture_output=True,
                text=True,
                check=False,
            )
            if probe.returncode == 0 and "CPU" in probe.stdout:
                break
            if head.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"ray did not start: {log.read_text(errors='replace')[-4000:]}")
            time.sleep(1)
        yield address
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
            head.wait()
        shutil.rmtree(temp, ignore_errors=True)


def test_ray_engine_on_a_local_cluster(
    ray_cluster: str, meshes: list[Path], bad_sources: list[Path], tmp_path: Path
) -> None:
    report = bake_many(
        [*meshes, *bad_sources], out=tmp_path, engine="ray", address=ray_cluster, progress=False, **OPTIONS
    )
    assert [r.status for r in report.results] == ["baked"] * 3 + ["failed"] * 2, report.summary()
    assert report.engine == "ray" and report.workers == 2
    assert os.getpid() not in {r.worker for r in report.baked}
    assert report.failed[0].error is not None and report.failed[0].error.startswith("MeshError")
    for mesh, result in zip(meshes, report.baked, strict=True):
        assert result.asset is not None
        here = lg.bake_mesh(lg.Mesh.load(mesh), progress=False, **OPTIONS).render(VIEW).color
        np.testing.assert_array_equal(frame_of(result.asset), here, err_msg=str(mesh))
    # The same batch through the local engine finds every asset made on Ray.
    local = bake_many(meshes, out=tmp_path, engine="local", progress=False, **OPTIONS)
    assert [r.status for r in local.results] == ["skipped"] * 3
