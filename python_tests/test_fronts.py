"""One quality request, four fronts: the CLI, HTTP, the WebSocket stream and the Python binding map
onto the same core type, so the same request renders bit-identical frames through each, and the
same conflict fails with the same text everywhere."""

from __future__ import annotations

import asyncio
import io
import json
import os
import socket
import struct
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

import lumigraph as lg

from websockets.asyncio import client as websockets

ROOT = Path(__file__).resolve().parents[1]
PROFILE = "debug" if os.environ.get("LUMIGRAPH_PROFILE") == "dev" else "release"
TARGET = Path(os.environ.get("CARGO_TARGET_DIR") or ROOT / "target")
BIN = Path(os.environ.get("LUMIGRAPH_BIN") or TARGET / PROFILE / "lumigraph")
VIEW = {"eye": [0.5, 0.6, 2.4], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40,
        "width": 96, "height": 80}
# Knobs away from their defaults, and a refined still: every part of the request must reach core.
QUALITY: dict[str, Any] = {"lod": 42, "step": 0.05, "guide": 8, "refine": 2}
CONFLICT: dict[str, Any] = {"target_psnr": 27, "guide": 8}
CONFLICT_TEXT = "target_psnr / budget_ms choose lod, step, tolerance, method and guide"
HEADER = struct.Struct("<4sHBBIIIIffIHH")


def cli_flags(quality: dict[str, Any]) -> list[str]:
    return [arg for key, value in quality.items() for arg in (f"--{key.replace('_', '-')}", str(value))]


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str]]:
    """A 42-camera demo asset and a `lumigraph serve` on it: (asset path, base URL)."""
    if not BIN.exists():
        pytest.fail(f"{BIN} is missing: build it with cargo build -p lumigraph_server")
    assets = tmp_path_factory.mktemp("assets")
    asset = assets / "demo.lfa"
    subprocess.run([str(BIN), "bake", "--demo", "-o", str(asset), "--cameras", "42",
                    "--resolution", "64", "--no-calibrate"], check=True, capture_output=True)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if k != "LUMIGRAPH_TOKEN"}
    server = subprocess.Popen([str(BIN), "serve", "--assets", str(assets), "--addr", f"127.0.0.1:{port}"],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 90
        while True:
            try:
                with urllib.request.urlopen(f"{base}/readyz", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            assert time.monotonic() < deadline and server.poll() is None, "server did not start"
            time.sleep(0.2)
        yield asset, base
    finally:
        server.terminate()
        server.wait(timeout=30)


def http_render(base: str, body: dict[str, Any]) -> tuple[int, bytes]:
    request = urllib.request.Request(f"{base}/v1/assets/demo/render", data=json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=60) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


async def stream(base: str, settings: dict[str, Any]) -> bytes | dict[str, Any]:
    """The still frame's PNG for `settings`, or the error message they are answered with."""
    async with websockets.connect(base.replace("http", "ws") + "/v1/stream?asset=demo",
                                  max_size=64 << 20) as ws:
        assert json.loads(await ws.recv())["type"] == "hello"
        await ws.send(json.dumps({"type": "settings", "interactive": False, "still_codec": "png",
                                  **settings}))
        await ws.send(json.dumps({"type": "view", "id": 1, "view": VIEW, "still": True}))
        while True:
            message = await asyncio.wait_for(ws.recv(), 60)
            if isinstance(message, str):
                parsed: dict[str, Any] = json.loads(message)
                return parsed
            header = HEADER.unpack_from(message)
            if header[5] == 1:  # the request id echoed
                return bytes(message[header[1]:])


def rgba(png: bytes) -> np.ndarray:
    image = Image.open(io.BytesIO(png))
    assert image.mode == "RGBA"
    return np.asarray(image)


def test_one_request_renders_the_same_frame_through_every_front(
    served: tuple[Path, str], tmp_path: Path
) -> None:
    asset, base = served
    python = lg.LightField.open(str(asset)).render(VIEW, **QUALITY)

    (tmp_path / "view.json").write_text(json.dumps(VIEW))
    subprocess.run([str(BIN), "render", str(asset), "--view", str(tmp_path / "view.json"),
                    "-o", str(tmp_path / "cli.png"), "--depth", str(tmp_path / "cli.npy"),
                    *cli_flags(QUALITY)], check=True, capture_output=True)
    status, http_png = http_render(base, {"view": VIEW, "format": "png", **QUALITY})
    assert status == 200, http_png
    status, http_npy = http_render(base, {"view": VIEW, "format": "none", "depth": "npy", **QUALITY})
    assert status == 200, http_npy
    stream_png = asyncio.run(stream(base, QUALITY))
    assert isinstance(stream_png, bytes), stream_png

    # Bit-identical: colour bytes and float32 depth (inf where nothing is hit) compare exactly.
    assert python.color.any(), "the view shows the demo"
    for name, png in [("cli", (tmp_path / "cli.png").read_bytes()), ("http", http_png),
                      ("stream", stream_png)]:
        np.testing.assert_array_equal(rgba(png), python.color, err_msg=name)
    np.testing.assert_array_equal(np.load(tmp_path / "cli.npy"), python.depth)
    np.testing.assert_array_equal(np.load(io.BytesIO(http_npy)), python.depth)


def test_one_conflict_fails_with_the_same_text_through_every_front(
    served: tuple[Path, str], tmp_path: Path
) -> None:
    asset, base = served
    with pytest.raises(ValueError) as python:
        lg.LightField.open(str(asset)).render(VIEW, **CONFLICT)

    (tmp_path / "view.json").write_text(json.dumps(VIEW))
    cli = subprocess.run([str(BIN), "render", str(asset), "--view", str(tmp_path / "view.json"),
                          "-o", str(tmp_path / "x.png"), *cli_flags(CONFLICT)],
                         capture_output=True, text=True, check=False)
    assert cli.returncode != 0
    status, http = http_render(base, {"view": VIEW, **CONFLICT})
    assert 400 <= status < 500, status
    ws = asyncio.run(stream(base, CONFLICT))
    assert isinstance(ws, dict) and ws["type"] == "error", ws

    texts = {"python": str(python.value), "cli": cli.stderr,
             "http": json.loads(http)["error"]["message"], "stream": ws["message"]}
    for front, text in texts.items():
        assert CONFLICT_TEXT in text, (front, text)
