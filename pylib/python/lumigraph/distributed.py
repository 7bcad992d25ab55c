"""Batch baking of many meshes, in local worker processes or on a Ray cluster.

::

    from lumigraph.distributed import bake_many
    report = bake_many(["a.glb", "b.ply", "c.obj"], out="assets/", engine="ray", cameras=42)
    print(report.summary())          # one line per failure, totals, bakes per minute
    for r in report.results:         # BakeResult: source, status, asset, seconds, error
        ...

Each source is baked by one worker process, which owns its own GPU device (created there on
first use, never pickled) and keeps it for every later bake it runs. ``threads_per_worker``
sets Mesa lavapipe's ``LP_NUM_THREADS`` in each worker, so that workers × threads matches the
machine's CPU slots instead of every worker starting one thread per core.

Outputs are **content-addressed and idempotent**: a source's asset is named
``<stem>-<key>.lfa`` where ``key`` is the first 16 hex digits of the SHA-256 of the source's
bytes, the bake options and the lumigraph version. An asset that exists is skipped, so a
batch that was stopped or partly failed is finished by running it again. Assets are written
atomically (a temp file renamed into place): a name that exists is a whole asset.

Engines:

- ``"local"``: a pool of ``workers`` processes on this machine (``spawn`` start method).
- ``"ray"``: one Ray task per source with ``num_cpus=threads_per_worker``. ``address`` names the
  cluster (``"auto"``, ``"127.0.0.1:6379"``, ``"ray://host:10001"``); without it, a Ray
  instance already initialised in this process is used, else a local one is started and shut
  down at the end. Ray is imported only for this engine (``pip install ray``); every node needs
  lumigraph installed and a Vulkan driver (``mesa-vulkan-drivers`` on CPU nodes).
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Literal

__all__ = ["BakeReport", "BakeResult", "asset_name", "bake_many"]

Engine = Literal["local", "ray"]
Status = Literal["baked", "skipped", "failed"]
_KEY_HEX = 16
_CHUNK = 1 << 20


@dataclass(frozen=True)
class BakeResult:
    """What happened to one source."""

    source: str
    #: ``"baked"``, ``"skipped"`` (its asset existed) or ``"failed"``.
    status: Status
    #: The asset's path (also for a skipped source); None when the source failed.
    asset: Path | None
    #: Wall-clock seconds of this source's bake in its worker (0 when skipped or not started).
    seconds: float = 0.0
    #: ``"ExceptionType: message"`` for a failure, else None.
    error: str | None = None
    #: The worker's process id (None when skipped or the worker was lost).
    worker: int | None = None


@dataclass
class BakeReport:
    """The outcome of :func:`bake_many`, in the order the sources were given."""

    results: list[BakeResult]
    engine: str
    workers: int
    threads_per_worker: int
    #: Wall-clock seconds of the whole batch, hashing and scheduling included.
    seconds: float
    options: dict[str, Any] = field(default_factory=dict)

    def _with(self, status: Status) -> list[BakeResult]:
        return [r for r in self.results if r.status == status]

    @property
    def baked(self) -> list[BakeResult]:
        return self._with("baked")

    @property
    def skipped(self) -> list[BakeResult]:
        return self._with("skipped")

    @property
    def failed(self) -> list[BakeResult]:
        return self._with("failed")

    @property
    def bakes_per_minute(self) -> float:
        """Assets baked per minute of the batch's wall-clock time (skips do not count)."""
        return 60.0 * len(self.baked) / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """Totals and throughput on the first line, then one line per failed source."""
        lines = [
            f"{len(self.baked)} baked, {len(self.skipped)} skipped, {len(self.failed)} failed "
            f"in {self.seconds:.1f} s ({self.bakes_per_minute:.1f} bakes/min; engine "
            f"{self.engine}, {self.workers} workers x {self.threads_per_worker} threads)"
        ]
        lines += [f"FAILED {r.source}: {r.error}" for r in self.failed]
        return "\n".join(lines)


def _bake_option_names() -> set[str]:
    from . import bake_mesh

    return {name for name in inspect.signature(bake_mesh).parameters if name not in ("mesh", "progress")}


def _canonical_options(options: Mapping[str, Any]) -> dict[str, Any]:
    allowed = _bake_option_names()
    unknown = sorted(set(options) - allowed)
    if unknown:
        raise TypeError(
            f"bake_many: unknown bake option(s) {', '.join(unknown)}; "
            f"bake_mesh takes {', '.join(sorted(allowed))}"
        )
    canonical: dict[str, Any] = {}
    for name, value in sorted(options.items()):
        if isinstance(value, tuple):
            value = list(value)
        try:
            json.dumps(value, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise TypeError(f"bake_many: option {name}={value!r} is not a plain JSON value: {e}") from None
        canonical[name] = value
    return canonical


def asset_name(source: str | os.PathLike[str], options: Mapping[str, Any]) -> str:
    """The file name :func:`bake_many` gives the asset of ``source`` baked with ``options``.

    Raises:
        OSError: the source cannot be read.
        TypeError: an unknown option or one that is not a plain JSON value.
    """
    from . import __version__

    path = Path(source)
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    digest.update(b"\0options\0")
    digest.update(json.dumps(_canonical_options(options), sort_keys=True).encode())
    digest.update(b"\0lumigraph\0" + __version__.encode())
    return f"{path.stem}-{digest.hexdigest()[:_KEY_HEX]}.lfa"


def _set_threads(threads: int) -> None:
    """Worker initializer: lavapipe reads LP_NUM_THREADS when the device is created, which
    happens on the worker's first bake, after this."""
    os.environ["LP_NUM_THREADS"] = str(threads)


def _bake_one(source: str, asset: str, options: dict[str, Any], threads: int | None) -> dict[str, Any]:
    """Bakes one source into ``asset`` inside a worker; never raises (a failure is a result)."""
    if threads is not None:
        _set_threads(threads)
    start = time.perf_counter()
    try:
        if os.path.exists(asset):
            return {"status": "skipped", "seconds": 0.0, "error": None, "worker": os.getpid()}
        from . import Mesh, bake_mesh

        mesh = Mesh.load(source)
        lf = bake_mesh(mesh, progress=False, **options)
        lf.save(asset)
        return {
            "status": "baked",
            "seconds": time.perf_counter() - start,
            "error": None,
            "worker": os.getpid(),
        }
    except Exception as e:  # noqa: BLE001 - every failure is reported per source
        return {
            "status": "failed",
            "seconds": time.perf_counter() - start,
            "error": f"{type(e).__name__}: {e}",
            "worker": os.getpid(),
        }


class _Progress:
    """``bake_many: 3/10 (1 failed, 2 skipped) 12 s`` on stderr, rewritten in place."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.total = total
        self.enabled = enabled and total > 0
        self.start = time.perf_counter()
        self.done = self.failed = self.skipped = 0

    def update(self, status: str) -> None:
        self.done += 1
        self.failed += status == "failed"
        self.skipped += status == "skipped"
        if self.enabled:
            end = "\n" if self.done >= self.total else ""
            print(
                f"\rbake_many: {self.done}/{self.total} ({self.failed} failed, {self.skipped} skipped) "
                f"{time.perf_counter() - self.start:.0f} s",
                end=end,
                file=sys.stderr,
                flush=True,
            )


def bake_many(
    sources: Iterable[str | os.PathLike[str]],
    *,
    out: str | os.PathLike[str],
    engine: Engine = "local",
    workers: int | None = None,
    threads_per_worker: int = 1,
    address: str | None = None,
    progress: bool = True,
    on_result: Callable[[BakeResult], object] | None = None,
    **bake_options: Any,
) -> BakeReport:
    """Bakes every mesh file in ``sources`` into ``out`` with :func:`lumigraph.bake_mesh`.

    Args:
        sources: mesh files (glTF/GLB, OBJ, PLY, STL, OFF). Each is read once here to name its
            asset (see the module docstring); the bake reads it again in its worker.
        out: the folder the assets go to (created if missing).
        engine: ``"local"`` (worker processes on this machine) or ``"ray"``.
        workers: local engine: the number of worker processes, default
            ``os.cpu_count() // threads_per_worker`` (at least 1). Ray: not used (the cluster's
            CPUs and ``threads_per_worker`` decide how many bakes run at once).
        threads_per_worker: lavapipe threads per worker (``LP_NUM_THREADS``) and, on Ray, the
            CPUs each task reserves; >= 1.
        address: Ray engine: the cluster address passed to ``ray.init``.
        progress: print a progress line for the batch to stderr (the workers' bakes are silent).
        on_result: called in this process with each :class:`BakeResult` as it arrives.
        **bake_options: passed to :func:`lumigraph.bake_mesh` (``cameras``, ``resolution``,
            ``auto``, ``target_psnr``, ...; not ``progress``). Checked here, before any work.

    Returns:
        A :class:`BakeReport`; sources that failed are in ``report.failed`` with their error.
        Nothing is raised for a source's failure.

    Raises:
        ValueError: an unknown engine, ``workers`` or ``threads_per_worker`` below 1, the same
            source twice, or ``address`` with the local engine.
        TypeError: an unknown bake option, or one that is not a plain JSON value.
        ImportError: ``engine="ray"`` without Ray installed.
    """
    if engine not in ("local", "ray"):
        raise ValueError(f"bake_many: engine must be 'local' or 'ray', got {engine!r}")
    if (
        isinstance(threads_per_worker, bool)
        or not isinstance(threads_per_worker, int)
        or threads_per_worker < 1
    ):
        raise ValueError(f"bake_many: threads_per_worker must be an integer >= 1, got {threads_per_worker!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"bake_many: workers must be an integer >= 1, got {workers!r}")
    if engine == "local" and address is not None:
        raise ValueError("bake_many: address is for engine='ray'")
    options = _canonical_options(bake_options)
    paths = [os.fspath(s) for s in sources]
    seen: set[str] = set()
    for p in paths:
        resolved = os.path.realpath(p)
        if resolved in seen:
            raise ValueError(f"bake_many: {p} is given twice")
        seen.add(resolved)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)

    start = time.perf_counter()
    bar = _Progress(len(paths), progress)
    results: list[BakeResult | None] = [None] * len(paths)

    def settle(i: int, result: BakeResult) -> None:
        results[i] = result
        bar.update(result.status)
        if on_result is not None:
            on_result(result)

    todo: list[tuple[int, str, str]] = []
    for i, source in enumerate(paths):
        try:
            asset = out_dir / asset_name(source, options)
        except OSError as e:
            settle(
                i,
                BakeResult(source, "failed", None, error=f"{type(e).__name__}: cannot read the source: {e}"),
            )
            continue
        if asset.exists():
            settle(i, BakeResult(source, "skipped", asset))
        else:
            todo.append((i, source, str(asset)))

    def finish(i: int, source: str, asset: str, outcome: Mapping[str, Any]) -> None:
        status: Status = outcome["status"]
        settle(
            i,
            BakeResult(
                source,
                status,
                Path(asset) if status != "failed" else None,
                seconds=float(outcome.get("seconds") or 0.0),
                error=outcome.get("error"),
                worker=outcome.get("worker"),
            ),
        )

    if engine == "local":
        count = workers or max(1, (os.cpu_count() or 1) // threads_per_worker)
        if todo:
            _run_local(todo, options, min(count, len(todo)), threads_per_worker, finish)
    else:
        count = 0
        if todo:
            count = _run_ray(todo, options, threads_per_worker, address, finish)

    done = [r for r in results if r is not None]
    assert len(done) == len(paths)
    return BakeReport(done, engine, count, threads_per_worker, time.perf_counter() - start, options)


_Finish = Callable[[int, str, str, Mapping[str, Any]], None]


def _run_local(
    todo: list[tuple[int, str, str]], options: dict[str, Any], workers: int, threads: int, finish: _Finish
) -> None:
    context = get_context("spawn")
    with ProcessPoolExecutor(
        workers, mp_context=context, initializer=_set_threads, initargs=(threads,)
    ) as pool:
        pending: dict[Future[dict[str, Any]], tuple[int, str, str]] = {
            pool.submit(_bake_one, source, asset, options, None): (i, source, asset)
            for i, source, asset in todo
        }
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                i, source, asset = pending.pop(future)
                try:
                    outcome = future.result()
                except Exception as e:  # noqa: BLE001 - a worker that died (BrokenProcessPool)
                    outcome = {"status": "failed", "error": f"worker lost: {type(e).__name__}: {e}"}
                finish(i, source, asset, outcome)


def _run_ray(
    todo: list[tuple[int, str, str]],
    options: dict[str, Any],
    threads: int,
    address: str | None,
    finish: _Finish,
) -> int:
    ray: Any = importlib.import_module("ray")
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=address, logging_level="WARNING", log_to_driver=False)
    try:
        task = ray.remote(_bake_one).options(
            num_cpus=threads,
            max_retries=1,
            runtime_env={"env_vars": {"LP_NUM_THREADS": str(threads)}},
        )
        pending = {
            task.remote(source, asset, options, threads): (i, source, asset) for i, source, asset in todo
        }
        cluster_cpus = float(ray.cluster_resources().get("CPU", 0.0))
        while pending:
            finished, _ = ray.wait(list(pending), num_returns=1)
            for ref in finished:
                i, source, asset = pending.pop(ref)
                try:
                    outcome = ray.get(ref)
                except Exception as e:  # noqa: BLE001 - a worker or node that was lost
                    outcome = {"status": "failed", "error": f"worker lost: {type(e).__name__}: {e}"}
                finish(i, source, asset, outcome)
        return max(1, math.floor(cluster_cpus / threads))
    finally:
        if started_here:
            ray.shutdown()
