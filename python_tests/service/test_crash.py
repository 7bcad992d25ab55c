"""Crash consistency: `kill -9` at random points of bakes, uploads and deletes, then a restart on
the same folder. After every restart:

- the listing is exactly the `.lfa` files of the folder (a partial or corrupt file would be
  skipped by the loader and show here), and each listed asset renders;
- no temporary file remains (`.upload-*.part`, `.ID.lfa.tmp-*`, journal temporaries);
- every upload answered 201 is listed and its file is byte-identical to what was sent;
- every delete answered 204 stays deleted;
- every bake answered 202 is known by its job id (queued, running or done) and, once done, its
  asset is listed (unless deleted after); at the end every one of them is done.

Operations whose answer the kill cut off may have happened or not; whatever they left must be
complete. The schedule comes from a seeded RNG (`LUMIGRAPH_CRASH_SEED`, printed with the
result) so a failure can be replayed.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import random
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

from conftest import Server, temporary_files

SEED = int(os.environ.get("LUMIGRAPH_CRASH_SEED", "20261203"))
KILLS_PER_MODE = 5
MIN_KILLS = 20
# A bake long enough (about 1 s on lavapipe) to be killed in the middle, and a quick one.
LONG_BAKE = {"cameras": 642, "resolution": 64}
SHORT_BAKE = {"cameras": 12, "resolution": 32}
KILL_MODES = [
    "during-start-up",
    "after-ready",
    "mid-bake",
    "mid-upload-body",
    "mid-bake-form",
    "in-flight",
    "after-ack",
]


Vec3 = tuple[float, float, float]
Triangle = tuple[int, int, int]


def icosphere(subdivisions: int) -> tuple[list[Vec3], list[Triangle]]:
    """A unit icosphere: vertices and triangles."""
    t = (1 + math.sqrt(5)) / 2
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
             (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    points = [tuple(c / math.sqrt(sum(x * x for x in v)) for c in v) for v in verts]
    vertices: list[Vec3] = [(p[0], p[1], p[2]) for p in points]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(subdivisions):
        midpoints: dict[tuple[int, int], int] = {}

        def middle(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in midpoints:
                m = [(vertices[a][i] + vertices[b][i]) / 2 for i in range(3)]
                norm = math.sqrt(sum(c * c for c in m))
                vertices.append((m[0] / norm, m[1] / norm, m[2] / norm))
                midpoints[key] = len(vertices) - 1
            return midpoints[key]

        finer: list[Triangle] = []
        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            finer += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = finer
    return vertices, faces


def mesh_file(rng: random.Random) -> tuple[str, bytes]:
    """An icosphere as OBJ or ASCII PLY, scaled and moved at random (distinct bakes)."""
    vertices, faces = icosphere(rng.randint(0, 2))
    scale = rng.uniform(0.5, 2.0)
    offset = [rng.uniform(-1, 1) for _ in range(3)]
    moved = [tuple(scale * v[i] + offset[i] for i in range(3)) for v in vertices]
    if rng.random() < 0.5:
        text = "".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in moved)
        text += "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)
        return "sphere.obj", text.encode()
    head = (f"ply\nformat ascii 1.0\nelement vertex {len(moved)}\nproperty float x\n"
            f"property float y\nproperty float z\nelement face {len(faces)}\n"
            "property list uchar int vertex_indices\nend_header\n")
    body = "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in moved)
    body += "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    return "sphere.ply", (head + body).encode()


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@dataclass
class Ledger:
    """What the server acknowledged, and what it may or may not have done."""

    uploads: dict[str, str] = field(default_factory=dict)  # id -> SHA-256 of the 201'd bytes
    deleted: set[str] = field(default_factory=set)  # ids answered 204
    deleting: set[str] = field(default_factory=set)  # ids a DELETE was sent for
    jobs: dict[str, str] = field(default_factory=dict)  # job id answered 202 -> asset id
    sent: dict[str, str] = field(default_factory=dict)  # id -> SHA-256 of any upload sent
    rendered: set[str] = field(default_factory=set)
    payloads: list[bytes] = field(default_factory=list)  # .lfa files to upload
    counter: int = 0
    kills: int = 0
    modes: dict[str, int] = field(default_factory=dict)
    acks: dict[str, int] = field(default_factory=lambda: {"201": 0, "202": 0, "204": 0})
    cut_off: int = 0  # requests in flight at a kill, answer unknown

    def new_id(self, prefix: str) -> str:
        self.counter += 1
        return f"{prefix}{self.counter}"


def listed(server: Server) -> dict[str, dict[str, Any]]:
    response = httpx.get(f"{server.base_url}/v1/assets", timeout=30)
    assert response.status_code == 200, response.text
    return {a["id"]: a for a in response.json()}


def render_ok(server: Server, asset: dict[str, Any]) -> None:
    c, r = asset["center"], max(asset["radius"], 1e-3)
    view = {"eye": [c[0], c[1] + 0.2 * r, c[2] + 3 * r], "target": c, "up": [0, 1, 0],
            "yfov_deg": 45, "width": 24, "height": 24}
    response = httpx.post(f"{server.base_url}/v1/assets/{asset['id']}/render",
                          json={"view": view}, timeout=60)
    assert response.status_code == 200, (asset["id"], response.text)
    assert response.content.startswith(b"\x89PNG")


def check(server: Server, ledger: Ledger, final: bool = False) -> dict[str, dict[str, Any]]:
    """Every invariant of the module docstring, on a freshly started (ready) server."""
    assets = server.assets
    # The bakes the start resumed may be writing (`.ID.lfa.tmp-PID-N` of this process); every
    # other temporary file is a killed server's and must be gone.
    left = [n for n in temporary_files(assets) if f".tmp-{server.pid}-" not in n]
    assert not left, f"temporary files after a restart: {left}"
    # Jobs first: one seen done has its asset listed by the time of the listing after.
    done: set[str] = set()
    for job_id, asset in ledger.jobs.items():
        response = httpx.get(f"{server.base_url}/v1/jobs/{job_id}", timeout=30)
        assert response.status_code == 200, f"job {job_id} was answered 202 and is lost"
        job = response.json()
        assert job["id"] == job_id and job["asset"] == asset, job
        assert job["state"] in ("queued", "running", "done"), job
        if final:
            assert job["state"] == "done", job
        if job["state"] == "done":
            done.add(asset)
    now = listed(server)
    for asset in done - ledger.deleting:
        assert asset in now, f"the job of {asset} is done but its asset is not listed"
    on_disk = {p.stem for p in assets.glob("*.lfa")}
    assert set(now) <= on_disk, f"listed {sorted(now)}, in the folder {sorted(on_disk)}"
    # A bake the start resumed lists its asset a moment after the file appears; any other file
    # not listed is one the server could not load: a partial or damaged asset.
    deadline = time.monotonic() + 10
    while on_disk - set(now) and time.monotonic() < deadline:
        time.sleep(0.05)
        now = listed(server)
    assert set(now) == on_disk, f"listed {sorted(now)}, in the folder {sorted(on_disk)}"
    for id_, digest in ledger.uploads.items():
        assert id_ in now, f"upload {id_} was answered 201 and is lost"
        assert sha((assets / f"{id_}.lfa").read_bytes()) == digest, f"upload {id_} changed"
    for id_ in now:
        if id_ in ledger.sent and id_ not in ledger.uploads:
            # An upload the kill cut off: there all of it, or not at all.
            assert sha((assets / f"{id_}.lfa").read_bytes()) == ledger.sent[id_], id_
    for id_ in ledger.deleted:
        assert id_ not in now, f"{id_} was deleted (204) and came back"
    for id_, summary in now.items():
        if id_ not in ledger.rendered:
            render_ok(server, summary)
            ledger.rendered.add(id_)
    return now


def wait_jobs_done(server: Server, ledger: Ledger, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    pending = set(ledger.jobs)
    while pending and time.monotonic() < deadline:
        for job_id in sorted(pending):
            job = httpx.get(f"{server.base_url}/v1/jobs/{job_id}", timeout=30).json()
            if job["state"] in ("done", "failed"):
                pending.discard(job_id)
        time.sleep(0.1)
    assert not pending, f"jobs not finished after {timeout} s: {sorted(pending)}"


# --- operations ---------------------------------------------------------------------------------


def upload(server: Server, ledger: Ledger, rng: random.Random) -> Callable[[], None]:
    """Returns the request to run; it records a 201 in the ledger."""
    data = rng.choice(ledger.payloads)
    id_ = ledger.new_id("up")
    ledger.sent[id_] = sha(data)

    def go() -> None:
        response = httpx.post(f"{server.base_url}/v1/assets?id={id_}", content=data, timeout=60)
        assert response.status_code == 201, response.text
        ledger.uploads[id_] = sha(data)
        ledger.acks["201"] += 1

    return go


def bake(server: Server, ledger: Ledger, rng: random.Random, options: dict[str, int]
         ) -> Callable[[], None]:
    name, mesh = mesh_file(rng)
    id_ = ledger.new_id("bake")

    def go() -> None:
        response = httpx.post(
            f"{server.base_url}/v1/bake",
            files={"mesh": (name, mesh, "application/octet-stream")},
            data={"options": json.dumps(options), "id": id_, "calibrate": "false"},
            timeout=60,
        )
        assert response.status_code == 202, response.text
        job = response.json()
        assert job["asset"] == id_
        ledger.jobs[job["id"]] = id_
        ledger.acks["202"] += 1

    return go


def delete(server: Server, ledger: Ledger, rng: random.Random) -> Callable[[], None] | None:
    candidates = sorted(a for a in listed(server) if a != "demo")
    if not candidates:
        return None
    id_ = rng.choice(candidates)
    # Until the 204 arrives the asset may be there or not (an upload's bytes still must match).
    ledger.deleting.add(id_)
    ledger.uploads.pop(id_, None)

    def go() -> None:
        response = httpx.delete(f"{server.base_url}/v1/assets/{id_}", timeout=60)
        assert response.status_code == 204, response.text
        ledger.deleted.add(id_)
        ledger.acks["204"] += 1

    return go


def any_operation(server: Server, ledger: Ledger, rng: random.Random) -> Callable[[], None]:
    kind = rng.choice(["upload", "upload", "bake", "delete", "delete"])
    if kind == "delete":
        op = delete(server, ledger, rng)
        if op is not None:
            return op
        kind = "upload"
    if kind == "upload":
        return upload(server, ledger, rng)
    return bake(server, ledger, rng, SHORT_BAKE)


def run_cut_off(op: Callable[[], None], delay: float, server: Server, ledger: Ledger) -> None:
    """Runs `op` in a thread and kills the server `delay` s after it starts."""
    errors: list[BaseException] = []

    def target() -> None:
        try:
            op()
        except (httpx.TransportError, AssertionError) as err:
            errors.append(err)

    thread = threading.Thread(target=target)
    thread.start()
    time.sleep(delay)
    server.kill()
    thread.join(timeout=60)
    assert not thread.is_alive()
    # A 4xx/5xx answer (an AssertionError) before the kill would be a bug, not a crash.
    for err in errors:
        if isinstance(err, AssertionError):
            raise err
    ledger.cut_off += len(errors)


def partial_request(server: Server, head: bytes, body: bytes, sent: int,
                    wait_for: Callable[[], bool]) -> None:
    """Sends `head` and the first `sent` bytes of `body`, waits until `wait_for()` (the server
    is writing), then kills the server."""
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    try:
        sock.sendall(head + body[:sent])
        deadline = time.monotonic() + 5
        while not wait_for() and time.monotonic() < deadline:
            time.sleep(0.01)
        server.kill()
    finally:
        sock.close()


def crash_round(server: Server, ledger: Ledger, rng: random.Random, mode: str) -> None:
    """A few complete operations, then the kill of `mode`."""
    for _ in range(rng.randint(0, 2)):
        any_operation(server, ledger, rng)()
    if mode == "after-ready":  # hits the bakes the start resumed
        time.sleep(rng.uniform(0.0, 0.6))
        server.kill()
    elif mode == "mid-bake":
        bake(server, ledger, rng, LONG_BAKE)()
        time.sleep(rng.uniform(0.05, 0.9))
        server.kill()
    elif mode == "mid-upload-body":
        data = rng.choice(ledger.payloads)
        id_ = ledger.new_id("partial")
        head = (f"POST /v1/assets?id={id_} HTTP/1.1\r\nHost: e2e\r\n"
                f"Content-Type: application/octet-stream\r\nContent-Length: {len(data)}\r\n\r\n")
        partial_request(server, head.encode(), data, rng.randint(1, len(data) - 1),
                        lambda: any(server.assets.glob(".upload-*.part")))
        ledger.deleted.add(id_)  # never complete: must never be listed
    elif mode == "mid-bake-form":
        name, mesh = mesh_file(rng)
        id_ = ledger.new_id("partialbake")
        boundary = "crash-boundary"
        body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"id\"\r\n\r\n{id_}\r\n"
                f"--{boundary}\r\nContent-Disposition: form-data; name=\"mesh\"; "
                f"filename=\"{name}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
                ).encode() + mesh + f"\r\n--{boundary}--\r\n".encode()
        head = (f"POST /v1/bake HTTP/1.1\r\nHost: e2e\r\nContent-Type: multipart/form-data; "
                f"boundary={boundary}\r\nContent-Length: {len(body)}\r\n\r\n")
        started = time.monotonic()
        partial_request(server, head.encode(), body, rng.randint(1, len(body) - 1),
                        lambda: time.monotonic() - started > 0.05)
        ledger.deleted.add(id_)  # never accepted: must never be listed
    elif mode == "in-flight":
        op = any_operation(server, ledger, rng)
        run_cut_off(op, rng.uniform(0.0, 0.12), server, ledger)
    elif mode == "after-ack":
        any_operation(server, ledger, rng)()
        server.kill()
    else:
        raise AssertionError(mode)


@pytest.mark.timeout(400)
def test_kill_9_at_random_points_loses_nothing_acknowledged(tmp_path: Path, demo_lfa: Path
                                                            ) -> None:
    rng = random.Random(SEED)
    assets = tmp_path / "assets"
    assets.mkdir()
    demo = demo_lfa.read_bytes()
    (assets / "demo.lfa").write_bytes(demo)
    ledger = Ledger(payloads=[demo])
    started = time.monotonic()
    servers: list[Server] = []

    def start() -> Server:
        server = Server(assets, tmp_path / f"server-{len(servers)}.log", None, [])
        servers.append(server)
        return server

    try:
        schedule = KILL_MODES * KILLS_PER_MODE
        rng.shuffle(schedule)
        for mode in schedule:
            server = start()
            if mode == "during-start-up":
                time.sleep(rng.uniform(0.0, 1.0))
                server.kill()
            else:
                server.wait_ready()
                check(server, ledger)
                if len(ledger.payloads) < 6:
                    # Distinct .lfa files to upload: the baked ones, read from the folder.
                    for baked in sorted(assets.glob("bake*.lfa")):
                        data = baked.read_bytes()
                        if len(data) < 200_000 and data not in ledger.payloads:
                            ledger.payloads.append(data)
                crash_round(server, ledger, rng, mode)
            ledger.kills += 1
            ledger.modes[mode] = ledger.modes.get(mode, 0) + 1
        # The last start: everything acknowledged is there and every bake finishes.
        server = start()
        server.wait_ready()
        check(server, ledger)
        wait_jobs_done(server, ledger, timeout=120)
        final = check(server, ledger, final=True)
        code = server.stop()
        assert code == 0, server.log_tail()
        assert not temporary_files(assets), temporary_files(assets)
    finally:
        for server in servers:
            with contextlib.suppress(Exception):
                server.kill()
    elapsed = time.monotonic() - started
    print(f"\ncrash test (seed {SEED}): survived {ledger.kills} kills in {elapsed:.1f} s; "
          f"kill points {dict(sorted(ledger.modes.items()))}; acknowledged {ledger.acks}; "
          f"{ledger.cut_off} requests cut off; {len(final)} assets at the end")
    assert ledger.kills >= MIN_KILLS


def journal_entry(job_id: str, asset: str, mesh_name: str, mesh: bytes, created: int) -> bytes:
    """A pending job as the server journals it (docs/protocol.md, Bake jobs)."""
    spec = {"id": job_id, "asset": asset, "options": {**SHORT_BAKE},
            "format": mesh_name.rpartition(".")[2],
            "calibrate": False, "source_name": mesh_name, "mesh_bytes": len(mesh),
            "mesh_sha256": sha(mesh), "created_unix_ms": created}
    return b"LUMIGRAPH-JOB 1\n" + json.dumps(spec).encode() + b"\n" + mesh


def test_journal_left_by_a_crash_is_resumed_or_cleaned(tmp_path: Path, demo_lfa: Path) -> None:
    """The states a kill can leave the journal in, planted: a job never started, a job whose
    asset was written before it was recorded, a job recorded done whose entry was not yet
    removed; and what the server never writes whole: torn entries and temporaries."""
    assets = tmp_path / "assets"
    journal = assets / ".jobs"
    journal.mkdir(parents=True)
    (assets / "demo.lfa").write_bytes(demo_lfa.read_bytes())
    name, mesh = mesh_file(random.Random(SEED))
    (journal / "job-queued.job").write_bytes(journal_entry("job-queued", "queued", name, mesh, 1))
    (journal / "job-written.job").write_bytes(
        journal_entry("job-written", "written", name, mesh, 2))
    (assets / "written.lfa").write_bytes(demo_lfa.read_bytes())
    done = {"finished_unix_ms": 5, "status": {
        "id": "job-done", "state": "done", "cameras_done": 12, "cameras_total": 12,
        "asset": "gone", "error": None, "report": {"asset_bytes": 1}}}
    (journal / "job-done.json").write_text(json.dumps(done))
    (journal / "job-done.job").write_bytes(journal_entry("job-done", "gone", name, mesh, 0))
    torn = journal_entry("job-torn", "torn", name, mesh, 3)
    (journal / "job-torn.job").write_bytes(torn[: len(torn) // 2])
    (journal / "job-garbage.json").write_text('{"finished_unix_ms": 1, "sta')
    (journal / ".job-x.job.tmp-1-0").write_bytes(b"half")
    server = Server(assets, tmp_path / "server.log", None, [])
    try:
        server.wait_ready()
        ledger = Ledger(jobs={"job-queued": "queued", "job-written": "written",
                              "job-done": "gone"}, deleting={"gone"})
        wait_jobs_done(server, ledger, timeout=60)
        check(server, ledger, final=True)
        written = httpx.get(f"{server.base_url}/v1/jobs/job-written", timeout=10).json()
        assert written["report"]["resumed"] is True, written
        assert written["cameras_done"] == 12, written
        for gone in ("job-torn", "job-garbage"):
            assert httpx.get(f"{server.base_url}/v1/jobs/{gone}", timeout=10).status_code == 404
        assert "gone" not in listed(server), "a job recorded done was baked again"
        assert sorted(p.name for p in journal.iterdir()) == [
            "job-done.json", "job-queued.json", "job-written.json"]
        assert "removed an unreadable job journal entry" in server.log_tail(200)
    finally:
        code = server.stop()
    assert code == 0, server.log_tail()
