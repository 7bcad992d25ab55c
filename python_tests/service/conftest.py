"""Fixtures of the render-service end-to-end tests (scripts/test_service_e2e.sh runs them).

Each server fixture starts `lumigraph serve` on a free loopback port in its own temporary assets
folder, pre-seeded with a small demo asset (12 cameras, 64 px maps) so startup skips the default
demo bake, waits for `/readyz`, and at the end stops it with SIGTERM and checks that it exits 0.

These tests need their own venv (httpx, websockets, playwright, pillow; see the script) and are
run with `-c python_tests/service/pytest.ini`. When the parent `python_tests/` suite
(scripts/test_python.sh, another venv) walks into this folder, it is skipped there.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
BIN = Path(os.environ.get("LUMIGRAPH_BIN") or ROOT / "target" / "release" / "lumigraph")
TOKEN = "e2e-secret-token"
MAX_PX = 2048
DEMO_CAMERAS = 12


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """Only collect these tests when run with this folder's pytest.ini (their own venv)."""
    inipath = config.inipath
    if inipath is None or inipath.resolve() != HERE / "pytest.ini":
        return True
    return None


# Lines for the end of the pytest report (e.g. how many cases the schema fuzzing ran), so that
# they show without `-s`.
SUMMARY: list[str] = []


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if SUMMARY:
        terminalreporter.write_sep("-", "service e2e summary")
        for line in SUMMARY:
            terminalreporter.write_line(line)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def runtime_env() -> dict[str, str]:
    env = dict(os.environ)
    runtime = env.get("XDG_RUNTIME_DIR")
    if not runtime or not os.path.isdir(runtime):
        runtime = tempfile.mkdtemp(prefix="lumigraph-xdg-")
        os.chmod(runtime, 0o700)
        env["XDG_RUNTIME_DIR"] = runtime
    env.pop("LUMIGRAPH_TOKEN", None)
    return env


def rss_kib(pid: int) -> int:
    """VmRSS of a process in KiB (from /proc/PID/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS in /proc/{pid}/status")


def metric(text: str, name: str, **labels: str) -> float:
    """Sum of the samples of `name` whose labels include `labels` (0 when absent)."""
    total = 0.0
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        key, _, value = line.rpartition(" ")
        metric_name, _, label_text = key.partition("{")
        if metric_name != name:
            continue
        if any(f'{k}="{v}"' not in label_text for k, v in labels.items()):
            continue
        total += float(value)
    return total


class Server:
    """A running `lumigraph serve`."""

    def __init__(
        self, assets: Path, log: Path, token: str | None, extra: list[str], max_px: int = MAX_PX
    ) -> None:
        self.assets = assets
        self.log_path = log
        self.token = token
        self.port = free_port()
        self.base_url = f"http://127.0.0.1:{self.port}"
        self.ws_url = f"ws://127.0.0.1:{self.port}"
        env = runtime_env()
        if token is not None:
            env["LUMIGRAPH_TOKEN"] = token
        self._log = log.open("wb")
        self.proc = subprocess.Popen(
            [str(BIN), "serve", "--assets", str(assets), "--addr", f"127.0.0.1:{self.port}",
             "--max-px", str(max_px), *extra],
            stdout=self._log, stderr=subprocess.STDOUT, env=env,
        )

    @property
    def pid(self) -> int:
        return self.proc.pid

    def log_tail(self, lines: int = 40) -> str:
        with contextlib.suppress(OSError):
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        return ""

    def wait_ready(self, timeout: float = 90.0) -> None:
        import httpx

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise AssertionError(
                    f"server exited with {self.proc.returncode} before ready:\n{self.log_tail()}")
            with contextlib.suppress(httpx.TransportError):
                if httpx.get(f"{self.base_url}/readyz", timeout=2).status_code == 200:
                    return
            time.sleep(0.1)
        raise AssertionError(f"server not ready after {timeout} s:\n{self.log_tail()}")

    def stop(self) -> int:
        """SIGTERM; returns the exit code (the process is killed after 20 s)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                self._log.close()
                raise AssertionError(f"server ignored SIGTERM for 20 s:\n{self.log_tail()}")
        self._log.close()
        return int(self.proc.returncode)

    def kill(self) -> None:
        """SIGKILL, as a crash: nothing of the server runs after it."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self._log.close()

    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def asset_files(self) -> set[str]:
        """Every entry of the assets folder (hidden temporary files included), except the bake
        job journal `.jobs/`, whose records come and go with jobs: of it only the temporary
        files, as `.jobs/NAME`."""
        return asset_files(self.assets)


JOURNAL = ".jobs"


def asset_files(assets: Path) -> set[str]:
    """See `Server.asset_files`."""
    names = {p.name for p in assets.iterdir() if p.name != JOURNAL}
    journal = assets / JOURNAL
    if journal.is_dir():
        names |= {f"{JOURNAL}/{p.name}" for p in journal.iterdir() if p.name.startswith(".")}
    return names


def temporary_files(assets: Path) -> list[str]:
    """Hidden files of the assets folder and of its job journal: what a write in progress (or a
    killed one) leaves; none should remain once a server has started or stopped."""
    return sorted(n for n in asset_files(assets) if n.startswith("."))


@pytest.fixture(scope="session")
def demo_lfa(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small demo asset, baked once per run."""
    if not BIN.is_file():
        pytest.fail(f"{BIN} is missing: build it with cargo build --release -p lumigraph_server")
    out = tmp_path_factory.mktemp("seed") / "demo.lfa"
    result = subprocess.run(
        [str(BIN), "bake", "--demo", "-o", str(out), "--cameras", str(DEMO_CAMERAS),
         "--resolution", "64"],
        capture_output=True, text=True, env=runtime_env(), timeout=120, check=False,
    )
    assert result.returncode == 0, f"demo bake failed:\n{result.stdout}\n{result.stderr}"
    return out


@contextlib.contextmanager
def running_server(
    tmp: Path, demo_lfa: Path, token: str | None = None, extra: list[str] | None = None,
    max_px: int = MAX_PX,
) -> Iterator[Server]:
    assets = tmp / "assets"
    assets.mkdir()
    shutil.copyfile(demo_lfa, assets / "demo.lfa")
    server = Server(assets, tmp / "server.log", token, extra or [], max_px)
    try:
        server.wait_ready()
        yield server
    finally:
        code = server.stop()
    assert code == 0, f"server exited with {code} after SIGTERM:\n{server.log_tail()}"
    assert not temporary_files(server.assets), (
        f"temporary files left in the assets folder: {server.asset_files()}")


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory, demo_lfa: Path) -> Iterator[Server]:
    """A server without a token (uploads and bakes open; loopback only)."""
    with running_server(tmp_path_factory.mktemp("server"), demo_lfa) as s:
        yield s


@pytest.fixture(scope="session")
def auth_server(tmp_path_factory: pytest.TempPathFactory, demo_lfa: Path) -> Iterator[Server]:
    """A server with LUMIGRAPH_TOKEN set and a session limit of 2."""
    with running_server(
        tmp_path_factory.mktemp("auth-server"), demo_lfa, token=TOKEN,
        extra=["--max-sessions", "2"],
    ) as s:
        yield s
