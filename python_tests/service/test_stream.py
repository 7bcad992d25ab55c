"""WebSocket `/v1/stream` end to end (docs/protocol.md): hello, frame headers, request ids echoed,
interactive then full quality, frames that match HTTP renders of the same view, errors that keep
the socket open, and flow control against clients that stop reading or acking."""

from __future__ import annotations

import asyncio
import io
import json
import math
import struct
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import httpx
import pytest
import websockets
from PIL import Image
from websockets.asyncio.client import ClientConnection, connect

from conftest import DEMO_CAMERAS, MAX_PX, Server, metric, rss_kib, running_server

T = TypeVar("T")
HEADER = struct.Struct("<4sHBBIIIIffIHBB")
CODECS = {0: "PNG", 1: "JPEG", 2: "WEBP"}


def run(coro: Callable[[], Awaitable[T]]) -> T:
    return asyncio.run(asyncio.wait_for(coro(), timeout=90))  # type: ignore[arg-type]


def view(angle: float = 0.0, width: int = 128, height: int = 96, dist: float = 10.0
         ) -> dict[str, Any]:
    return {"eye": [dist * math.sin(angle), 1.0, dist * math.cos(angle)], "target": [0, 0, 0],
            "up": [0, 1, 0], "yfov_deg": 40, "width": width, "height": height}


@dataclass
class Frame:
    header_len: int
    codec: int
    quality: int
    frame_id: int
    request_id: int
    width: int
    height: int
    render_ms: float
    encode_ms: float
    dropped: int
    cameras: int
    jpeg_quality: int
    flags: int
    image: bytes
    size: int

    def decode(self) -> Image.Image:
        image = Image.open(io.BytesIO(self.image))
        image.load()
        assert image.format == CODECS[self.codec], (image.format, self.codec)
        assert image.size == (self.width, self.height), (image.size, self.width, self.height)
        return image


def parse_frame(data: bytes) -> Frame:
    assert len(data) > HEADER.size
    (magic, header_len, codec, quality, frame_id, request_id, width, height, render_ms, encode_ms,
     dropped, cameras, jpeg_quality, flags) = HEADER.unpack_from(data)
    assert magic == b"LGF1", magic
    assert header_len == 40
    return Frame(header_len, codec, quality, frame_id, request_id, width, height, render_ms,
                 encode_ms, dropped, cameras, jpeg_quality, flags, data[header_len:], len(data))


class Session:
    """A stream client that records frames and error messages."""

    def __init__(self, ws: ClientConnection, hello: dict[str, Any]) -> None:
        self.ws = ws
        self.hello = hello
        self.frames: list[Frame] = []
        self.errors: list[dict[str, Any]] = []

    async def send(self, message: Any) -> None:
        await self.ws.send(message if isinstance(message, (str, bytes)) else json.dumps(message))

    async def view(self, request_id: int, v: dict[str, Any], still: bool = False) -> None:
        await self.send({"type": "view", "id": request_id, "view": v, "still": still})

    async def next(self, ack: bool = True, timeout: float = 30) -> Frame | dict[str, Any]:
        message = await asyncio.wait_for(self.ws.recv(), timeout)
        if isinstance(message, str):
            parsed = json.loads(message)
            assert parsed["type"] == "error", parsed
            self.errors.append(parsed)
            return parsed
        frame = parse_frame(message)
        if ack:
            await self.send({"type": "ack", "frame": frame.frame_id})
        if self.frames:
            assert frame.frame_id == self.frames[-1].frame_id + 1, "frame ids are consecutive"
        self.frames.append(frame)
        return frame

    async def frame(self, pred: Callable[[Frame], bool], timeout: float = 30) -> Frame:
        deadline = time.monotonic() + timeout
        while True:
            message = await self.next(timeout=max(0.1, deadline - time.monotonic()))
            if isinstance(message, Frame) and pred(message):
                return message

    async def error(self, timeout: float = 10) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            message = await self.next(timeout=max(0.1, deadline - time.monotonic()))
            if isinstance(message, dict):
                return message


async def open_session(server: Server, asset: str | None = "demo", **kw: Any) -> Session:
    query = f"?asset={asset}" if asset is not None else ""
    ws = await connect(f"{server.ws_url}/v1/stream{query}", max_size=64 << 20, **kw)
    hello = json.loads(await ws.recv())
    return Session(ws, hello)


def http_png(server: Server, v: dict[str, Any]) -> Image.Image:
    response = httpx.post(f"{server.base_url}/v1/assets/demo/render",
                          json={"view": v, "format": "png"}, timeout=60)
    assert response.status_code == 200, response.text
    return Image.open(io.BytesIO(response.content))


def mean_abs_diff(a: Image.Image, b: Image.Image) -> float:
    assert a.size == b.size
    pa, pb = a.convert("RGBA").tobytes(), b.convert("RGBA").tobytes()
    return sum(abs(x - y) for x, y in zip(pa, pb, strict=True)) / len(pa)


def metrics_text(server: Server) -> str:
    return httpx.get(f"{server.base_url}/metrics", timeout=10).text


# --- sessions ------------------------------------------------------------------------------------


def test_hello(server: Server) -> None:
    async def body() -> None:
        s = await open_session(server, asset=None)
        hello = s.hello
        assert hello["type"] == "hello" and hello["protocol"] == 1
        assert hello["header_len"] == 40 and hello["max_px"] == MAX_PX
        assert hello["asset"]["id"] == "demo"
        assert hello["asset"]["camera_count"] == DEMO_CAMERAS
        settings = hello["settings"]
        assert settings["still_codec"] == "jpeg" and settings["interactive_codec"] == "jpeg"
        assert settings["max_in_flight"] == 2 and settings["rest_ms"] == 250
        assert settings["adaptive"] is True
        await s.ws.close()

    run(body)


def test_session_changes_views_and_gets_matching_frames(server: Server) -> None:
    async def body() -> None:
        s = await open_session(server)
        await s.send({"type": "settings", "interactive_scale": 0.5, "rest_ms": 50,
                      "still_codec": "png"})
        full: dict[int, Frame] = {}
        for request_id, angle in ((11, 0.0), (12, 0.9), (13, 2.2)):
            await s.view(request_id, view(angle))
            interactive = await s.frame(lambda f: f.request_id == request_id)
            assert interactive.quality == 0 and interactive.codec == 1
            assert (interactive.width, interactive.height) == (64, 48)
            interactive.decode()
            still = await s.frame(lambda f: f.request_id == request_id and f.quality == 1)
            assert still.codec == 0 and (still.width, still.height) == (128, 96)
            full[request_id] = still
        assert not s.errors, s.errors
        # A view sent with still: true gets exactly one frame, at full quality.
        await s.view(14, view(3.0), still=True)
        only = await s.frame(lambda f: f.request_id == 14)
        assert only.quality == 1 and (only.width, only.height) == (128, 96)
        with pytest.raises(TimeoutError):
            await s.next(timeout=0.6)
        for f in s.frames:
            assert f.header_len == 40 and f.cameras == DEMO_CAMERAS
            # JPEG interactive frames at the default q50, lossless PNG stills; the link (loopback,
            # acks without receive times) never adapted anything.
            assert f.jpeg_quality == (50 if f.codec == 1 else 0) and f.flags == 0
            assert f.render_ms > 0 and f.encode_ms >= 0 and f.dropped == 0
            assert f.request_id in (11, 12, 13, 14)
        assert [f.frame_id for f in s.frames] == list(range(1, len(s.frames) + 1))
        # The full-quality frames show their views: they match HTTP renders of the same view and
        # differ from each other.
        images = {rid: f.decode() for rid, f in full.items()}
        for rid, angle in ((11, 0.0), (12, 0.9), (13, 2.2)):
            assert mean_abs_diff(images[rid], http_png(server, view(angle))) < 1.0, rid
        assert mean_abs_diff(images[11], images[12]) > 3.0
        assert mean_abs_diff(images[12], images[13]) > 3.0
        await s.ws.close()

    run(body)


def test_settings_change_rerenders_with_new_codec_and_lod(server: Server) -> None:
    async def body() -> None:
        s = await open_session(server)
        await s.send({"type": "settings", "interactive": False})
        await s.view(1, view(0.4))
        first = await s.frame(lambda f: f.request_id == 1)
        assert first.quality == 1 and first.codec == 1  # interactive off: full at once, jpeg
        first.decode()
        await s.send({"type": "settings", "still_codec": "webp"})
        webp = await s.frame(lambda f: f.codec == 2)
        assert webp.request_id == 1 and webp.quality == 1
        webp.decode()
        await s.send({"type": "settings", "still_codec": "png", "background": [255, 0, 0, 255]})
        red = await s.frame(lambda f: f.codec == 0)
        assert red.decode().convert("RGBA").getpixel((0, 0)) == (255, 0, 0, 255)
        await s.send({"type": "settings", "layers": {"default": 0.5}, "background": [0, 0, 0, 0]})
        half = await s.frame(lambda f: f.frame_id > red.frame_id)
        alphas = {a for a in half.decode().getchannel("A").tobytes()}
        assert max(alphas) <= 128, sorted(alphas)[-5:]
        assert not s.errors, s.errors
        await s.ws.close()

    run(body)


@pytest.mark.parametrize(("message", "request_id", "kind"), [
    ("not json", None, "malformed_json"),
    ('{"type": "view", "id": 5, "view": {"eye": [NaN, 0, 3]}}', None, "malformed_json"),
    ({"type": "view", "id": 5, "view": {**view(), "yfov_deg": 0}}, 5, "invalid"),
    ({"type": "view", "id": 6, "view": {**view(), "yfov_deg": 180}}, 6, "invalid"),
    ({"type": "view", "id": 7, "view": {**view(), "width": MAX_PX + 1}}, 7, "invalid"),
    ({"type": "view", "id": 8, "view": {**view(), "up": [0, 0, 0]}}, 8, "invalid"),
    ({"type": "view", "id": 9, "view": {**view(), "eye": [0, 0, 0]}}, 9, "invalid"),
    ({"type": "view", "id": 10, "view": view(), "extra": 1}, 10, "invalid"),
    ({"type": "zoom", "id": 3}, 3, "invalid"),
    ({"id": 4}, 4, "invalid"),
    ({"type": "settings", "target_fps": 0}, None, "invalid"),
    ({"type": "settings", "rest_ms": 20000}, None, "invalid"),
    ({"type": "settings", "max_in_flight": 3}, None, "invalid"),
    ({"type": "settings", "still_codec": "gif"}, None, "invalid"),
    ({"type": "settings", "layers": {"nope": 1}}, None, "invalid"),
    ({"type": "settings", "bogus": 1}, None, "invalid"),
    ({"type": "ack", "frame": -1}, None, "invalid"),
    ({"type": "ack", "frame": 1, "received_ms": -5}, None, "invalid"),
    ({"type": "ack", "frame": 1, "received_ms": "now"}, None, "invalid"),
    (b"\x00\x01binary", None, "bad_message"),
])
def test_bad_messages_answer_errors_and_keep_the_socket(
    server: Server, message: Any, request_id: int | None, kind: str
) -> None:
    async def body() -> None:
        s = await open_session(server)
        await s.send(message)
        error = await s.error()
        assert error == {"type": "error", "request": request_id, "kind": kind,
                         "message": error["message"]}, error
        assert error["message"]
        # The socket stays open, the settings are unchanged (default still codec: jpeg).
        await s.view(99, view(1.0), still=True)
        frame = await s.frame(lambda f: f.request_id == 99)
        assert frame.quality == 1 and frame.codec == 1 and frame.width == 128
        await s.ws.close()

    run(body)
    assert httpx.get(f"{server.base_url}/readyz").status_code == 200


def test_a_refused_message_is_answered_before_the_next_frame(server: Server) -> None:
    """Refused settings then a view, sent back to back: the error comes first, every time (the
    order the client sent them), though the sender may find the view waiting when it wakes."""
    async def body() -> None:
        s = await open_session(server)
        for request_id in range(1, 31):
            await s.send({"type": "settings", "still_codec": "gif"})
            await s.view(request_id, view(0.1 * request_id), still=True)
            first = await s.next()
            assert isinstance(first, dict), f"round {request_id}: a frame came before the error"
            assert first["kind"] == "invalid" and "gif" in first["message"], first
            await s.frame(lambda f, r=request_id: f.request_id == r)
        await s.ws.close()

    run(body)


@pytest.mark.parametrize(("asset", "status", "kind"), [
    ("nope", 404, "not_found"), ("..%2Fdemo", 422, "invalid"), ("%2e%2e", 422, "invalid"),
    ("demo.lfa", 422, "invalid")])
def test_stream_refused_before_upgrade(server: Server, asset: str, status: int, kind: str) -> None:
    async def body() -> None:
        with pytest.raises(websockets.exceptions.InvalidStatus) as info:
            await open_session(server, asset=asset)
        response = info.value.response
        assert response.status_code == status
        assert json.loads(response.body)["error"]["kind"] == kind

    run(body)


def test_session_limit_is_503(auth_server: Server) -> None:
    """The auth server allows 2 sessions; a third gets 503 before the upgrade."""
    async def body() -> None:
        a = await open_session(auth_server)
        b = await open_session(auth_server)
        with pytest.raises(websockets.exceptions.InvalidStatus) as info:
            await open_session(auth_server)
        assert info.value.response.status_code == 503
        assert json.loads(info.value.response.body)["error"]["kind"] == "unavailable"
        await a.ws.close()
        await b.ws.close()
        # Slots come back once sessions end.
        for _ in range(50):
            try:
                c = await open_session(auth_server)
            except websockets.exceptions.InvalidStatus:
                await asyncio.sleep(0.1)
                continue
            await c.ws.close()
            return
        raise AssertionError("the session slots were not released")

    run(body)


# --- flow control --------------------------------------------------------------------------------

BIG = {"width": 512, "height": 512}
RSS_GROWTH_LIMIT_KIB = 64 << 10


def test_client_that_stops_acking_gets_dropped_frames(server: Server) -> None:
    """No acks: at most `max_in_flight` frames are sent, newer views replace older ones (dropped,
    counted in the header and /metrics), memory stays flat, and an ack resumes with the newest."""
    async def body() -> None:
        s = await open_session(server)
        await s.send({"type": "settings", "interactive": False, "still_codec": "png"})
        for i in range(3):  # warm up 512x512 renders so their buffers exist before measuring
            await s.view(i + 1, {**view(i * 0.3), **BIG})
            await s.frame(lambda f, rid=i + 1: f.request_id == rid)
        warm = len(s.frames)
        dropped_before = metric(metrics_text(server), "lumigraph_dropped_frames_total")
        rss_before = rss_kib(server.pid)
        views = 400
        for i in range(views):
            await s.view(1000 + i, {**view(i * 0.01), **BIG})
            await asyncio.sleep(0.005)
        await asyncio.sleep(1.0)
        rss_after = rss_kib(server.pid)
        assert rss_after - rss_before < RSS_GROWTH_LIMIT_KIB, (rss_before, rss_after)
        # Without acks the server sent at most two more frames.
        stalled: list[Frame] = []
        while True:
            try:
                message = await s.next(ack=False, timeout=1.5)
            except TimeoutError:
                break
            assert isinstance(message, Frame), message
            stalled.append(message)
        assert 1 <= len(stalled) <= 2, [f.request_id for f in stalled]
        # Ack: the server resumes with the newest view; everything between was dropped.
        await s.send({"type": "ack", "frame": stalled[-1].frame_id})
        latest = await s.frame(lambda f: f.request_id == 1000 + views - 1)
        assert latest.frame_id == s.frames[warm - 1].frame_id + len(stalled) + 1
        assert latest.dropped >= views - len(stalled) - 1 - 2, latest.dropped
        dropped_after = metric(metrics_text(server), "lumigraph_dropped_frames_total")
        assert dropped_after - dropped_before >= latest.dropped, (dropped_before, dropped_after)
        assert rss_kib(server.pid) - rss_before < RSS_GROWTH_LIMIT_KIB
        await s.ws.close()

    run(body)


def test_client_that_stops_reading_gets_dropped_frames(server: Server) -> None:
    """A client that acks everything but never reads its socket: the server blocks on the full
    TCP buffers instead of queueing frames; views are dropped, memory stays flat."""
    async def body() -> None:
        # max_queue=1: the client library stops reading the socket once one message is buffered.
        s = await open_session(server, max_queue=1)
        await s.send({"type": "settings", "interactive": False, "still_codec": "png"})
        await s.view(1, {**view(0.0), **BIG})
        await s.frame(lambda f: f.request_id == 1)
        dropped_before = metric(metrics_text(server), "lumigraph_dropped_frames_total")
        rss_before = rss_kib(server.pid)
        views = 300
        for i in range(views):
            await s.view(2000 + i, {**view(i * 0.02), **BIG})
            await s.send({"type": "ack", "frame": 1 << 30})
            await asyncio.sleep(0.01)
        await asyncio.sleep(1.0)
        rss_after = rss_kib(server.pid)
        assert rss_after - rss_before < RSS_GROWTH_LIMIT_KIB, (rss_before, rss_after)
        # Now read everything: far fewer frames than views, ending with the newest view.
        received = []
        while True:
            message = await s.next(ack=False, timeout=30)
            assert isinstance(message, Frame), message
            message.decode()
            received.append(message)
            if message.request_id == 2000 + views - 1 and message.quality == 1:
                break
        assert len(received) < views // 2, len(received)
        dropped_after = metric(metrics_text(server), "lumigraph_dropped_frames_total")
        assert dropped_after - dropped_before >= views // 2, (dropped_before, dropped_after)
        assert received[-1].dropped >= views // 2
        await s.ws.close()

    run(body)


def test_sessions_metric_and_stream_frames_counted(server: Server) -> None:
    async def body() -> None:
        before = metrics_text(server)
        s = await open_session(server)
        await s.view(1, view(), still=True)
        await s.frame(lambda f: f.request_id == 1)
        during = metrics_text(server)
        assert metric(during, "lumigraph_stream_sessions") >= 1
        assert metric(during, "lumigraph_frames_total", source="stream") > metric(
            before, "lumigraph_frames_total", source="stream")
        assert metric(during, "lumigraph_bytes_sent_total", source="stream") > metric(
            before, "lumigraph_bytes_sent_total", source="stream")
        await s.ws.close()

    run(body)


# --- shutdown ------------------------------------------------------------------------------------


def test_sigterm_closes_sessions_and_exits_cleanly(tmp_path: Path, demo_lfa: Path) -> None:
    with running_server(tmp_path, demo_lfa) as own:
        async def body() -> float:
            s = await open_session(own)
            await s.view(1, view(), still=True)
            await s.frame(lambda f: f.request_id == 1)
            stopped = threading.Event()
            started = time.monotonic()
            threading.Thread(target=lambda: (own.proc.send_signal(15), stopped.set()),
                             daemon=True).start()
            with pytest.raises(websockets.exceptions.ConnectionClosed):
                while True:
                    await s.next(timeout=15)
            assert stopped.wait(5)
            return time.monotonic() - started

        assert run(body) < 12
        assert own.proc.wait(timeout=15) == 0, own.log_tail()
