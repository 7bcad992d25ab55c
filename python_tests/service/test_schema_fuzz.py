"""Schema fuzzing: Schemathesis generates requests from the live server's `/openapi.json` and
runs every check on the answers (`--checks all`: no 5xx; status codes, content types, headers
and bodies as documented; schema-violating requests refused, schema-valid ones accepted;
auth enforced), once on a server without a token and once on one with a token (requests sent
with it; Schemathesis also retries them without it and expects 401). Any failure fails the test
with Schemathesis' report, which holds a `curl` line reproducing each failure.

Bounded for CI: LUMIGRAPH_FUZZ_EXAMPLES cases per operation and phase (default 100; about a
minute for both servers on two cores). The seed is random unless LUMIGRAPH_FUZZ_SEED is set;
the summary at the end of the pytest report gives it, with the number of cases each run
generated. The servers use `--max-px 64`, the schema's bound on a view's size, so that every
generated render (up to 256 refinement samples) stays cheap on a software rasterizer.

python_tests/service/schemathesis.toml says what is allowed beyond Schemathesis' defaults and
why: only the statuses of schema-valid requests whose validity the schema cannot express.
"""

from __future__ import annotations

import json
import os
import random
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from conftest import HERE, SUMMARY, TOKEN, Server, metric, running_server

EXAMPLES = int(os.environ.get("LUMIGRAPH_FUZZ_EXAMPLES", "100"))
FUZZ_MAX_PX = 64
CONFIG = HERE / "schemathesis.toml"
SCHEMATHESIS = Path(sys.executable).parent / "schemathesis"
# A regular tetrahedron (OFF), baked so that a real job and a second asset exist.
TETRA_OFF = b"OFF\n4 4 0\n1 1 1\n-1 -1 1\n-1 1 -1\n1 -1 -1\n3 0 1 2\n3 0 3 1\n3 0 2 3\n3 1 3 2\n"


def bake_tetra(server: Server) -> str:
    """Bakes the tetrahedron as asset `fuzz-tetra`; returns the finished job's id."""
    response = httpx.post(
        f"{server.base_url}/v1/bake", headers=server.auth(),
        files={"mesh": ("tetra.off", TETRA_OFF, "application/octet-stream")},
        data={"options": json.dumps({"cameras": 12, "resolution": 32}), "id": "fuzz-tetra",
              "calibrate": "false"},
        timeout=60,
    )
    assert response.status_code == 202, response.text
    job = response.json()
    deadline = time.monotonic() + 60
    while job["state"] not in ("done", "failed") and time.monotonic() < deadline:
        time.sleep(0.1)
        job = httpx.get(f"{server.base_url}/v1/jobs/{job['id']}", timeout=10).json()
    assert job["state"] == "done", job
    return str(job["id"])


def write_config(path: Path, assets: list[str], jobs: list[str], deletable: list[str]) -> None:
    """schemathesis.toml with the dictionaries of this server's real ids appended."""
    def values(ids: list[str]) -> str:
        return ", ".join(json.dumps(i) for i in ids)

    path.write_text(
        CONFIG.read_text()
        + f"\n[dictionaries.assets]\nvalues = [{values(assets)}]\n"
        + f"\n[dictionaries.jobs]\nvalues = [{values(jobs)}]\n"
        + f"\n[dictionaries.deletable]\nvalues = [{values(deletable)}]\n"
    )


def schemathesis(server: Server, workdir: Path, config: Path, label: str, seed: int,
                 operations: list[str]) -> int:
    """Runs Schemathesis against `server`; fails with its report unless every check passed.
    Returns the number of generated cases."""
    command = [
        str(SCHEMATHESIS), "--config-file", str(config), "--no-color", "run",
        f"{server.base_url}/openapi.json", "--checks", "all", "--max-examples", str(EXAMPLES),
        "--seed", str(seed), "--workers", "1", "--request-timeout", "60",
        "--generation-database", "none", "--warnings", "off", *operations,
    ]
    if server.token:
        command += ["--header", f"Authorization: Bearer {server.token}"]
    started = time.monotonic()
    result = subprocess.run(command, cwd=workdir, capture_output=True, text=True, timeout=300,
                            check=False)
    seconds = time.monotonic() - started
    output = result.stdout + result.stderr
    (workdir / f"schemathesis-{label}.log").write_text(output)
    found = re.search(r"(\d+) generated", output)
    cases = int(found.group(1)) if found else 0
    SUMMARY.append(f"schemathesis {label}: {cases} cases in {seconds:.0f} s "
                   f"(seed {seed}, {EXAMPLES} examples per operation and phase), "
                   f"exit {result.returncode}")
    assert result.returncode == 0, (
        f"schemathesis {label} (seed {seed}) failed, exit {result.returncode}:\n{output[-20000:]}"
        f"\n--- server log ---\n{server.log_tail()}")
    assert cases > 0, f"schemathesis {label} generated no case:\n{output[-4000:]}"
    assert server.proc.poll() is None, f"server died during {label}:\n{server.log_tail()}"
    return cases


@pytest.mark.timeout(600)
@pytest.mark.parametrize("token", [None, TOKEN], ids=["open", "token"])
def test_schema_fuzz(tmp_path: Path, demo_lfa: Path, token: str | None) -> None:
    seed = int(os.environ.get("LUMIGRAPH_FUZZ_SEED") or random.randrange(2**31))
    label = "token" if token else "open"
    with running_server(tmp_path, demo_lfa, token=token, max_px=FUZZ_MAX_PX) as server:
        job = bake_tetra(server)
        spares = ["spare-1", "spare-2"]
        for spare in spares:
            upload = httpx.post(f"{server.base_url}/v1/assets?id={spare}", headers=server.auth(),
                                content=demo_lfa.read_bytes(), timeout=60)
            assert upload.status_code == 201, upload.text
        config = tmp_path / "schemathesis.toml"
        write_config(config, ["demo", "fuzz-tetra"], [job], [*spares, "fuzz-tetra", "demo"])
        # Deletes last, in their own run: the others need the assets.
        cases = schemathesis(server, tmp_path, config, label, seed,
                             ["--exclude-name", "DELETE /v1/assets/{id}"])
        cases += schemathesis(server, tmp_path, config, f"{label} deletes", seed,
                              ["--include-name", "DELETE /v1/assets/{id}"])
        metrics = httpx.get(f"{server.base_url}/metrics", timeout=10).text
        assert metric(metrics, "lumigraph_errors_total", kind="internal") == 0, (
            f"internal errors during fuzzing:\n{server.log_tail()}")
        assert "panicked" not in server.log_tail(10_000), server.log_tail()
    SUMMARY.append(f"schemathesis {label} total: {cases} cases")
