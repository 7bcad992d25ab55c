"""HTTP API end to end: render round trips, assets, uploads, bakes, auth and every bad input of
the issue (each answered with a JSON error of the right status, the server healthy afterwards
and no partial file left in the assets folder)."""

from __future__ import annotations

import ast
import contextlib
import http.client
import http.server
import io
import json
import math
import signal
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from PIL import Image

from conftest import (BIN, DEMO_CAMERAS, MAX_PX, TOKEN, Server, free_port, metric, runtime_env,
                      running_server)

VIEW: dict[str, Any] = {"eye": [0.3, 1.0, 10.0], "target": [0, 0, 0], "up": [0, 1, 0],
                        "yfov_deg": 40, "width": 96, "height": 64}


def render(server: Server, body: Any, asset: str = "demo", **kw: Any) -> httpx.Response:
    return httpx.post(f"{server.base_url}/v1/assets/{asset}/render", json=body, timeout=60, **kw)


def raw_render(server: Server, content: bytes, asset: str = "demo") -> httpx.Response:
    return httpx.post(f"{server.base_url}/v1/assets/{asset}/render", content=content, timeout=60,
                      headers={"Content-Type": "application/json"})


def parse_npy(data: bytes) -> tuple[tuple[int, ...], list[float]]:
    """A minimal .npy reader (float32 little-endian, C order) that checks the format."""
    assert data[:6] == b"\x93NUMPY", data[:16]
    major = data[6]
    if major == 1:
        (hlen,) = struct.unpack_from("<H", data, 8)
        start = 10
    else:
        (hlen,) = struct.unpack_from("<I", data, 8)
        start = 12
    header = ast.literal_eval(data[start:start + hlen].decode("latin1"))
    assert header["descr"] == "<f4" and header["fortran_order"] is False, header
    shape = tuple(header["shape"])
    body = data[start + hlen:]
    count = math.prod(shape)
    assert (start + hlen) % 16 == 0 or major == 1
    assert len(body) == 4 * count, (len(body), shape)
    return shape, list(struct.unpack(f"<{count}f", body))


def parse_multipart(content_type: str, body: bytes) -> list[tuple[dict[str, str], bytes]]:
    """Parts of a multipart/mixed body, read by each part's Content-Length."""
    boundary = content_type.split("boundary=", 1)[1].strip().encode()
    parts = []
    pos = 0
    while True:
        marker = b"--" + boundary
        assert body.startswith(marker, pos), body[pos:pos + 80]
        pos += len(marker)
        if body.startswith(b"--", pos):
            break
        assert body.startswith(b"\r\n", pos)
        head_end = body.index(b"\r\n\r\n", pos)
        headers = {}
        for line in body[pos + 2:head_end].decode().split("\r\n"):
            k, _, v = line.partition(":")
            headers[k.strip().lower()] = v.strip()
        start = head_end + 4
        length = int(headers["content-length"])
        parts.append((headers, body[start:start + length]))
        pos = start + length
        assert body.startswith(b"\r\n", pos)
        pos += 2
    return parts


def assert_error(response: httpx.Response, status: int, kind: str) -> dict[str, Any]:
    assert response.status_code == status, (response.status_code, response.text)
    assert response.headers["content-type"].startswith("application/json")
    error = response.json()["error"]
    assert error["kind"] == kind, error
    assert isinstance(error["message"], str) and error["message"]
    return error


def assert_healthy(server: Server, files_before: set[str]) -> None:
    """The process is alive, answers health and renders, and the folder did not change."""
    assert server.proc.poll() is None, server.log_tail()
    assert httpx.get(f"{server.base_url}/healthz", timeout=10).status_code == 200
    assert httpx.get(f"{server.base_url}/readyz", timeout=10).status_code == 200
    ok = render(server, {"view": VIEW})
    assert ok.status_code == 200, ok.text
    assert server.asset_files() == files_before, (files_before, server.asset_files())


# --- health, assets, metrics ---------------------------------------------------------------------


def test_health_ready_openapi(server: Server) -> None:
    assert httpx.get(f"{server.base_url}/healthz").json() == {"status": "ok"}
    ready = httpx.get(f"{server.base_url}/readyz").json()
    assert ready["ready"] is True and ready["assets"] == 1 and ready["adapter"]
    spec = httpx.get(f"{server.base_url}/openapi.json").json()
    assert spec["openapi"].startswith("3.")
    for path in ("/v1/assets", "/v1/assets/{id}", "/v1/assets/{id}/render", "/v1/bake",
                 "/v1/jobs/{id}", "/v1/stream", "/healthz", "/readyz", "/metrics"):
        assert path in spec["paths"], path


def test_openapi_describes_what_the_server_accepts(server: Server, auth_server: Server) -> None:
    """The document's request schemas match the server's validation (schema fuzzing found each
    of these; test_schema_fuzz.py runs the fuzzer)."""
    spec = httpx.get(f"{server.base_url}/openapi.json").json()
    schemas = spec["components"]["schemas"]
    body = schemas["RenderRequest"]
    # One closed object with the quality keys beside `view` (an allOf of two closed objects
    # matched no body at all).
    assert "allOf" not in body and body["additionalProperties"] is False
    assert body["required"] == ["view"]
    for key in ("view", "format", "depth", "lod", "step", "target_psnr", "auto_lod", "refine"):
        assert key in body["properties"], key
    assert body["properties"]["method"]["oneOf"][1]["enum"] == ["fixed", "default"]
    assert body["properties"]["quality"]["minimum"] == 1
    assert body["properties"]["quality"]["maximum"] == 100
    assert body["properties"]["background"]["items"]["maximum"] == 255
    # `format` and `up` may be left out but not sent as null, which the server refuses.
    assert body["properties"]["format"] == {
        "$ref": "#/components/schemas/ColorFormat",
        "description": body["properties"]["format"]["description"]}
    assert_error(render(server, {"view": VIEW, "format": None}), 422, "invalid")
    view = schemas["ViewSchema"]
    assert view["properties"]["up"]["type"] == "array" and "up" not in view["required"]
    assert_error(render(server, {"view": {**VIEW, "up": None}}), 422, "invalid")
    assert view["additionalProperties"] is False
    assert view["properties"]["width"]["maximum"] == MAX_PX
    assert view["properties"]["height"]["maximum"] == MAX_PX
    # Every body the schema allows with only these keys renders.
    ok = render(server, {"view": VIEW, "method": "fixed", "quality": 100, "background": [255] * 4,
                         "format": "jpeg"})
    assert ok.status_code == 200, ok.text
    form = schemas["BakeForm"]
    assert form["additionalProperties"] is False
    assert form["properties"]["calibrate"]["pattern"] == r"^\s*(true|false)\s*$"
    # The token requirement is documented only where a token is configured.
    for own, secured in ((server, False), (auth_server, True)):
        doc = httpx.get(f"{own.base_url}/openapi.json").json()
        for path, method in (("/v1/assets", "post"), ("/v1/bake", "post"),
                             ("/v1/assets/{id}", "delete")):
            assert ("security" in doc["paths"][path][method]) is secured, (path, method, own)


def test_assets_list_and_detail(server: Server) -> None:
    listed = httpx.get(f"{server.base_url}/v1/assets").json()
    demo = next(a for a in listed if a["id"] == "demo")
    for key in ("kind", "camera_count", "resolution_px", "layers", "states", "center", "radius",
                "file_bytes"):
        assert key in demo, key
    assert demo["camera_count"] == DEMO_CAMERAS and demo["resolution_px"] == 64
    detail = httpx.get(f"{server.base_url}/v1/assets/demo").json()
    assert detail["id"] == "demo" and isinstance(detail["header"], dict)
    assert detail["file_bytes"] == (server.assets / "demo.lfa").stat().st_size


# --- render round trips --------------------------------------------------------------------------


@pytest.mark.parametrize(("fmt", "pil_format", "mime"), [
    ("png", "PNG", "image/png"), ("jpeg", "JPEG", "image/jpeg"), ("webp", "WEBP", "image/webp")])
def test_render_formats(server: Server, fmt: str, pil_format: str, mime: str) -> None:
    body = {"view": VIEW, "format": fmt, "background": [10, 20, 30, 255]}
    if fmt == "jpeg":
        body["quality"] = 80
    response = render(server, body)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == mime
    assert float(response.headers["x-render-ms"]) > 0
    assert float(response.headers["x-encode-ms"]) >= 0
    assert response.headers["x-frame-width"] == "96" and response.headers["x-frame-height"] == "64"
    image = Image.open(io.BytesIO(response.content))
    image.load()
    assert image.format == pil_format and image.size == (96, 64)
    rgb = image.convert("RGB")
    colours = rgb.getcolors(maxcolors=96 * 64)
    assert colours is not None and len(colours) > 8, "the frame is (nearly) uniform"
    corner = rgb.getpixel((0, 0))
    assert all(abs(c - e) <= 6 for c, e in zip(corner, (10, 20, 30), strict=True)), corner


def test_render_transparent_png_and_lossless_webp_agree(server: Server) -> None:
    png = Image.open(io.BytesIO(render(server, {"view": VIEW, "format": "png"}).content))
    webp = Image.open(io.BytesIO(render(server, {"view": VIEW, "format": "webp"}).content))
    assert png.mode == "RGBA"
    assert png.getpixel((0, 0))[3] == 0, "background defaults to transparent"
    assert png.convert("RGBA").tobytes() == webp.convert("RGBA").tobytes()


def test_render_link_is_the_post_render_and_revalidates(server: Server) -> None:
    """`GET /v1/assets/{id}/render?...`: the POST render's bytes, with a tag a client can hold."""
    query = {"eye": "0.3,1,10", "target": "0,0,0", "up": "0,1,0", "yfov_deg": "40",
             "width": str(VIEW["width"]), "height": str(VIEW["height"]), "lod": "12",
             "format": "png", "background": "0,0,0,255"}
    link = httpx.get(f"{server.base_url}/v1/assets/demo/render", params=query, timeout=60)
    assert link.status_code == 200, link.text
    assert link.headers["content-type"] == "image/png"
    posted = render(server, {"view": VIEW, "lod": 12, "format": "png",
                             "background": [0, 0, 0, 255]})
    assert link.content == posted.content
    assert Image.open(io.BytesIO(link.content)).size == (VIEW["width"], VIEW["height"])
    assert link.headers["cache-control"] == "public, max-age=300"
    held = httpx.get(f"{server.base_url}/v1/assets/demo/render", params=query, timeout=60,
                     headers={"If-None-Match": link.headers["etag"]})
    assert held.status_code == 304 and not held.content
    bad = httpx.get(f"{server.base_url}/v1/assets/demo/render", params={**query, "zoom": "2"},
                    timeout=60)
    assert bad.status_code == 422 and "zoom" in bad.json()["error"]["message"]
    missing = httpx.get(f"{server.base_url}/v1/assets/nope/render", params=query, timeout=60)
    assert missing.status_code == 404 and missing.json()["error"]["kind"] == "not_found"


def test_render_depth_npy_alone(server: Server) -> None:
    response = render(server, {"view": VIEW, "format": "none", "depth": "npy"})
    assert response.status_code == 200, response.text
    shape, values = parse_npy(response.content)
    assert shape == (64, 96)
    finite = [v for v in values if math.isfinite(v)]
    assert finite, "no pixel hit the object"
    assert any(math.isinf(v) for v in values), "no background pixel"
    # The demo fits in a sphere of radius ~3.55 around the origin, seen from ~10 units away.
    assert 5.5 < min(finite) and max(finite) < 14.5, (min(finite), max(finite))


def test_render_color_and_depth_multipart(server: Server) -> None:
    response = render(server, {"view": VIEW, "format": "png", "depth": "npy"})
    assert response.status_code == 200, response.text
    content_type = response.headers["content-type"]
    assert content_type.startswith("multipart/mixed; boundary=")
    (color_headers, color), (depth_headers, depth) = parse_multipart(content_type, response.content)
    assert color_headers["content-type"] == "image/png"
    assert 'name="color"' in color_headers["content-disposition"]
    assert 'name="depth"' in depth_headers["content-disposition"]
    assert Image.open(io.BytesIO(color)).size == (96, 64)
    shape, values = parse_npy(depth)
    assert shape == (64, 96)
    # Colour alpha and depth agree on what was hit.
    alpha = Image.open(io.BytesIO(color)).getchannel("A").tobytes()
    hits = [a > 0 for a in alpha]
    finite = [math.isfinite(v) for v in values]
    agree = sum(h == f for h, f in zip(hits, finite, strict=True)) / len(hits)
    assert agree > 0.97, agree


def test_render_depth_png16_range_headers(server: Server) -> None:
    response = render(server, {"view": VIEW, "format": "none", "depth": "png16"})
    assert response.status_code == 200, response.text
    near, far = float(response.headers["x-depth-near"]), float(response.headers["x-depth-far"])
    assert 0 < near < far
    image = Image.open(io.BytesIO(response.content))
    assert image.size == (96, 64) and image.mode.startswith("I")


def test_render_metrics_count_frames(server: Server) -> None:
    before = httpx.get(f"{server.base_url}/metrics").text
    assert render(server, {"view": VIEW, "format": "jpeg"}).status_code == 200
    after = httpx.get(f"{server.base_url}/metrics")
    assert after.headers["content-type"].startswith("application/openmetrics-text")
    text = after.text
    assert text.rstrip().endswith("# EOF")
    frames = metric(text, "lumigraph_frames_total", source="http")
    assert frames == metric(before, "lumigraph_frames_total", source="http") + 1
    assert metric(text, "lumigraph_bytes_sent_total", source="http") > metric(
        before, "lumigraph_bytes_sent_total", source="http")
    assert metric(text, "lumigraph_encode_seconds_count", codec="jpeg") >= 1
    assert metric(text, "lumigraph_assets") >= 1


# --- uploads and bakes -------------------------------------------------------------------------

CUBE_OFF = b"""OFF
8 12 0
-0.5 -0.5 -0.5
0.5 -0.5 -0.5
0.5 0.5 -0.5
-0.5 0.5 -0.5
-0.5 -0.5 0.5
0.5 -0.5 0.5
0.5 0.5 0.5
-0.5 0.5 0.5
3 0 2 1
3 0 3 2
3 4 5 6
3 4 6 7
3 0 1 5
3 0 5 4
3 2 3 7
3 2 7 6
3 1 2 6
3 1 6 5
3 0 4 7
3 0 7 3
"""


def test_upload_render_delete(server: Server) -> None:
    data = (server.assets / "demo.lfa").read_bytes()
    files = server.asset_files()
    created = httpx.post(f"{server.base_url}/v1/assets?id=copy1", content=data, timeout=60)
    assert created.status_code == 201, created.text
    assert created.headers["location"] == "/v1/assets/copy1"
    assert created.json()["id"] == "copy1"
    assert server.asset_files() == files | {"copy1.lfa"}
    assert render(server, {"view": VIEW}, asset="copy1").status_code == 200
    conflict = httpx.post(f"{server.base_url}/v1/assets?id=copy1", content=data, timeout=60)
    assert_error(conflict, 409, "conflict")
    assert httpx.delete(f"{server.base_url}/v1/assets/copy1").status_code == 204
    assert_error(render(server, {"view": VIEW}, asset="copy1"), 404, "not_found")
    assert server.asset_files() == files


def test_bake_job(server: Server) -> None:
    files = server.asset_files()
    response = httpx.post(
        f"{server.base_url}/v1/bake",
        files={"mesh": ("cube.off", CUBE_OFF, "application/octet-stream")},
        data={"options": json.dumps({"cameras": 12, "resolution": 32}), "id": "cube"},
        timeout=60,
    )
    assert response.status_code == 202, response.text
    job = response.json()
    assert response.headers["location"] == f"/v1/jobs/{job['id']}"
    deadline = time.monotonic() + 60
    while job["state"] not in ("done", "failed") and time.monotonic() < deadline:
        time.sleep(0.2)
        job = httpx.get(f"{server.base_url}/v1/jobs/{job['id']}").json()
    assert job["state"] == "done", job
    assert job["asset"] == "cube" and job["cameras_done"] == job["cameras_total"] == 12
    assert render(server, {"view": VIEW}, asset="cube").status_code == 200
    assert server.asset_files() == files | {"cube.lfa"}
    assert httpx.delete(f"{server.base_url}/v1/assets/cube").status_code == 204
    assert server.asset_files() == files


@pytest.mark.timeout(600)  # the job's own deadline: three calibration bakes in a debug build
def test_auto_bake_job(server: Server) -> None:
    """`POST /v1/bake` with `auto`: the calibration, the choice and the held-out measurement run
    in the job; a budget below every setting bakes the smallest setting and says so."""
    files = server.asset_files()
    try:
        check_auto_bake_job(server)
    finally:
        # The server is shared with later tests: they must not see this asset.
        httpx.delete(f"{server.base_url}/v1/assets/cube-auto", timeout=60)
    assert server.asset_files() == files


def check_auto_bake_job(server: Server) -> None:
    response = httpx.post(
        f"{server.base_url}/v1/bake",
        files={"mesh": ("cube.off", CUBE_OFF, "application/octet-stream")},
        data={"auto": json.dumps({"max_bytes": 1}), "calibrate": "false", "id": "cube-auto",
              "options": json.dumps({"shading": {"ambient": 0.3}})},
        timeout=60,
    )
    assert response.status_code == 202, response.text
    job = response.json()
    deadline = time.monotonic() + 540  # inside the test's timeout, so the assertion says why
    while job["state"] not in ("done", "failed") and time.monotonic() < deadline:
        time.sleep(0.5)
        job = httpx.get(f"{server.base_url}/v1/jobs/{job['id']}").json()
    assert job["state"] == "done", job
    report = job["report"]
    assert (report["cameras"], report["resolution"]) == (12, 64), report
    auto = report["auto_bake"]
    assert auto["target"] == {"max_bytes": 1}
    assert auto["choice"]["reach"] == "budget_too_small" and auto["target_met"] is False
    assert "max bytes 1 is below the smallest setting" in auto["message"]
    assert math.isfinite(auto["measured_psnr"]) and auto["held_out_views"] == 24
    info = httpx.get(f"{server.base_url}/v1/assets/cube-auto").json()
    assert (info["camera_count"], info["resolution_px"]) == (12, 64), info
    assert render(server, {"view": VIEW}, asset="cube-auto").status_code == 200
    assert httpx.delete(f"{server.base_url}/v1/assets/cube-auto").status_code == 204


def healthcheck(port: int, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN), "healthcheck", "--addr", f"127.0.0.1:{port}", *extra],
                          capture_output=True, text=True, timeout=60, env=runtime_env())


def test_a_gpu_asked_for_and_absent_fails_readiness_with_the_reason(tmp_path: Path) -> None:
    """`LUMIGRAPH_ADAPTER=gpu` on a machine with only a software rasterizer: the process stays
    up (liveness 200, no crash loop), /readyz and every other path answer 503 with the reason,
    the log says it once, `healthcheck` fails, and SIGTERM ends it cleanly."""
    port = free_port()
    log = tmp_path / "serve.log"
    env = {**runtime_env(), "LUMIGRAPH_ADAPTER": "gpu"}
    with open(log, "w") as log_file:
        proc = subprocess.Popen([str(BIN), "serve", "--assets", str(tmp_path / "assets"),
                                 "--addr", f"127.0.0.1:{port}"], env=env, stdout=log_file,
                                stderr=subprocess.STDOUT)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while True:
            try:
                alive = httpx.get(f"{base}/healthz", timeout=5)
                break
            except httpx.TransportError:
                assert proc.poll() is None, log.read_text()
                assert time.monotonic() < deadline, "serve did not start listening"
                time.sleep(0.2)
        assert alive.status_code == 200
        ready = httpx.get(f"{base}/readyz", timeout=5)
        if ready.status_code == 200:
            pytest.skip("this machine has a hardware GPU: LUMIGRAPH_ADAPTER=gpu found it")
        assert ready.status_code == 503 and ready.headers["retry-after"] == "1"
        message = ready.json()["error"]["message"]
        assert "LUMIGRAPH_ADAPTER=gpu: no such adapter; found" in message, message
        assert "only software rasterizers" in message and "llvmpipe" in message, message
        other = httpx.post(f"{base}/v1/assets/demo/render", json={}, timeout=5)
        assert other.status_code == 503 and other.json()["error"]["message"] == message
        check = healthcheck(port)
        assert check.returncode == 1 and "LUMIGRAPH_ADAPTER=gpu" in check.stderr, check.stderr
        assert not (tmp_path / "assets").exists() or not any((tmp_path / "assets").iterdir())
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=30)
    text = log.read_text()
    assert code == 0, text
    assert text.count("not ready") == 1 and "LUMIGRAPH_ADAPTER=gpu" in text, text
    assert "panicked" not in text, text


def test_healthcheck_command(server: Server) -> None:
    """`lumigraph healthcheck` (for container HEALTHCHECKs): exit 0 with the readiness JSON
    from a ready service; a clear error and exit 1 when nothing listens, when the service
    answers 503 (its reason shown), or when it does not answer in time."""
    ok = healthcheck(server.port)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith("ready: ") and json.loads(ok.stdout[7:])["ready"] is True

    closed = free_port()
    refused = healthcheck(closed)
    assert refused.returncode == 1 and "cannot connect" in refused.stderr, refused.stderr

    # A stand-in answering 503 the way the service does while it loads; then one that accepts
    # and never answers.
    class NotReady(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (the handler API's name)
            body = json.dumps({"error": {"kind": "unavailable",
                                         "message": "loading assets"}}).encode()
            self.send_response(503)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: Any) -> None:
            pass

    stand_in = http.server.HTTPServer(("127.0.0.1", 0), NotReady)
    thread = threading.Thread(target=stand_in.serve_forever, daemon=True)
    thread.start()
    try:
        busy = healthcheck(stand_in.server_address[1])
        assert busy.returncode == 1, busy
        assert "503" in busy.stderr and "loading assets" in busy.stderr, busy.stderr
    finally:
        stand_in.shutdown()
        stand_in.server_close()
    with socket.create_server(("127.0.0.1", 0)) as silent:
        slow = healthcheck(silent.getsockname()[1], "--timeout-secs", "0.5")
        assert slow.returncode == 1 and "no answer" in slow.stderr, slow.stderr


# --- bad input ---------------------------------------------------------------------------------

BODY = json.dumps({"view": VIEW})


def with_view(**changes: Any) -> dict[str, Any]:
    return {"view": {**VIEW, **changes}}


@pytest.mark.parametrize(("content", "why"), [
    (b'{"view": ', "truncated"),
    (b"not json at all", "syntax"),
    (BODY.replace("0.3", "NaN").encode(), "NaN literal"),
    (BODY.replace("0.3", "Infinity").encode(), "Infinity literal"),
    (BODY.replace("0.3", "-Infinity").encode(), "-Infinity literal"),
    (BODY.replace("0.3", "1e999").encode(), "overflowing number"),
    (b"", "empty body"),
])
def test_malformed_json_is_400(server: Server, content: bytes, why: str) -> None:
    files = server.asset_files()
    assert_error(raw_render(server, content), 400, "malformed_json")
    assert_healthy(server, files)


@pytest.mark.parametrize(("body", "why"), [
    (with_view(width=MAX_PX + 1), "width above the cap"),
    (with_view(height=MAX_PX + 1), "height above the cap"),
    (with_view(width=0), "zero width"),
    (with_view(width=-5), "negative width"),
    (with_view(yfov_deg=0), "fov 0"),
    (with_view(yfov_deg=180), "fov 180"),
    (with_view(yfov_deg=-10), "negative fov"),
    (with_view(yfov_deg=400), "fov above 180"),
    (with_view(up=[0, 0, 0]), "zero-length up"),
    (with_view(eye=[0, 0, 10], up=[0, 0, 1]), "up parallel to the view direction"),
    (with_view(eye=[0, 0, 0], target=[0, 0, 0]), "eye == target"),
    (with_view(eye=[1, 2, 3], target=[1, 2, 3]), "eye == target off the origin"),
    (with_view(eye=[0, 0, 10], up=[0, 0, -2]), "up anti-parallel to the view direction"),
    ({"view": VIEW, "quality": 0, "format": "jpeg"}, "jpeg quality 0"),
    ({"view": VIEW, "quality": 101, "format": "jpeg"}, "jpeg quality 101"),
    ({"view": VIEW, "lod": 7}, "lod not a camera count"),
    ({"view": VIEW, "lod": 642}, "lod above the asset's cameras"),
    ({"view": VIEW, "step": -1}, "negative step"),
    ({"view": VIEW, "tolerance": 0}, "zero tolerance"),
    ({"view": VIEW, "format": "gif"}, "unknown format"),
    ({"view": VIEW, "depth": "tiff"}, "unknown depth format"),
    ({"view": VIEW, "format": "none"}, "format none without depth"),
    ({"view": VIEW, "background": [0, 0, 0, 256]}, "background out of u8"),
    ({"view": VIEW, "bogus": 1}, "unknown field"),
    ({"view": {**VIEW, "width": "512"}}, "wrong type"),
    ({"format": "png"}, "missing view"),
    ([1, 2, 3], "not an object"),
])
def test_invalid_render_is_422(server: Server, body: Any, why: str) -> None:
    files = server.asset_files()
    assert_error(render(server, body), 422, "invalid")
    assert_healthy(server, files)


def test_errors_are_counted_by_kind(server: Server) -> None:
    before = metric(httpx.get(f"{server.base_url}/metrics").text, "lumigraph_errors_total",
                    kind="invalid")
    assert render(server, with_view(yfov_deg=0)).status_code == 422
    after = metric(httpx.get(f"{server.base_url}/metrics").text, "lumigraph_errors_total",
                   kind="invalid")
    assert after == before + 1


def test_unknown_asset_route_and_job_are_404(server: Server) -> None:
    files = server.asset_files()
    assert_error(render(server, {"view": VIEW}, asset="nope"), 404, "not_found")
    assert_error(httpx.get(f"{server.base_url}/v1/assets/nope"), 404, "not_found")
    assert_error(httpx.delete(f"{server.base_url}/v1/assets/nope"), 404, "not_found")
    assert_error(httpx.get(f"{server.base_url}/v1/jobs/job-0000"), 404, "not_found")
    assert_error(httpx.get(f"{server.base_url}/v2/nothing"), 404, "not_found")
    assert_error(httpx.put(f"{server.base_url}/v1/assets"), 405, "rejected")
    assert_healthy(server, files)


def test_oversized_json_body_is_413(server: Server) -> None:
    files = server.asset_files()
    body = json.dumps({"view": VIEW, "pad": "x" * (70 << 10)}).encode()
    assert_error(raw_render(server, body), 413, "too_large")
    assert_healthy(server, files)


def test_oversized_upload_is_413_before_reading(auth_server: Server) -> None:
    """A declared Content-Length above the 4 GiB .lfa limit is refused before any byte is read."""
    files = auth_server.asset_files()
    conn = http.client.HTTPConnection("127.0.0.1", auth_server.port, timeout=30)
    conn.putrequest("POST", "/v1/assets?id=huge")
    conn.putheader("Authorization", f"Bearer {TOKEN}")
    conn.putheader("Content-Type", "application/octet-stream")
    conn.putheader("Content-Length", str(5 << 30))
    conn.endheaders()
    try:
        conn.send(b"LFA" * 1000)
        response = conn.getresponse()
        body = json.loads(response.read())
    finally:
        conn.close()
    assert response.status == 413, body
    assert body["error"]["kind"] == "too_large"
    assert_healthy(auth_server, files)


def test_oversized_bake_form_is_413(server: Server) -> None:
    """A mesh form above the 512 MiB limit: refused with 413 while it streams in, nothing kept."""
    files = server.asset_files()
    limit = 512 << 20
    head = (b'--XyZ\r\nContent-Disposition: form-data; name="mesh"; filename="a.off"\r\n'
            b"Content-Type: application/octet-stream\r\n\r\n")
    total = len(head) + limit + (1 << 20)
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=60)
    try:
        sock.sendall(b"POST /v1/bake HTTP/1.1\r\nHost: e2e\r\n"
                     b"Content-Type: multipart/form-data; boundary=XyZ\r\n"
                     + f"Content-Length: {total}\r\n\r\n".encode() + head)
        chunk = b"0" * (1 << 20)
        sent = len(head)
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            while sent < total:
                sock.sendall(chunk)
                sent += len(chunk)
        reply = b""
        with contextlib.suppress(ConnectionResetError):
            while b"\r\n\r\n" not in reply or not reply.rstrip().endswith(b"}"):
                data = sock.recv(65536)
                if not data:
                    break
                reply += data
    finally:
        sock.close()
    status_line, _, rest = reply.partition(b"\r\n")
    assert status_line.startswith(b"HTTP/1.1 413"), reply[:300]
    body = json.loads(rest.partition(b"\r\n\r\n")[2])
    assert body["error"]["kind"] == "too_large"
    assert_healthy(server, files)


# --- auth ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("headers", [
    {}, {"Authorization": "Bearer wrong"}, {"Authorization": f"Basic {TOKEN}"},
    {"Authorization": f"Bearer {TOKEN}x"}, {"Authorization": TOKEN}])
def test_bad_token_is_401(auth_server: Server, headers: dict[str, str]) -> None:
    files = auth_server.asset_files()
    data = (auth_server.assets / "demo.lfa").read_bytes()
    responses = [
        httpx.post(f"{auth_server.base_url}/v1/assets?id=x1", content=data, headers=headers),
        httpx.post(f"{auth_server.base_url}/v1/bake", headers=headers,
                   files={"mesh": ("cube.off", CUBE_OFF)}, data={"id": "x2"}),
        httpx.delete(f"{auth_server.base_url}/v1/assets/demo", headers=headers),
    ]
    for response in responses:
        assert_error(response, 401, "unauthorized")
        assert response.headers["www-authenticate"] == "Bearer"
    assert_healthy(auth_server, files)
    assert httpx.get(f"{auth_server.base_url}/v1/assets/demo").status_code == 200


def test_good_token_uploads_and_reads_stay_open(auth_server: Server) -> None:
    files = auth_server.asset_files()
    assert render(auth_server, {"view": VIEW}).status_code == 200
    data = (auth_server.assets / "demo.lfa").read_bytes()
    created = httpx.post(f"{auth_server.base_url}/v1/assets?id=tok", content=data,
                         headers=auth_server.auth(), timeout=60)
    assert created.status_code == 201, created.text
    deleted = httpx.delete(f"{auth_server.base_url}/v1/assets/tok", headers=auth_server.auth())
    assert deleted.status_code == 204
    assert auth_server.asset_files() == files


# --- malformed uploads -------------------------------------------------------------------------


def corrupt(data: bytes, offset: int) -> bytes:
    return data[:offset] + bytes([data[offset] ^ 0xFF]) + data[offset + 1:]


@pytest.mark.parametrize("kind", ["garbage", "empty", "truncated", "flipped-late", "flipped-mid",
                                  "header-only"])
def test_malformed_asset_upload_is_422(server: Server, kind: str) -> None:
    files = server.asset_files()
    data = (server.assets / "demo.lfa").read_bytes()
    body = {
        "garbage": b"this is not an lfa file" * 100,
        "empty": b"",
        "truncated": data[: len(data) // 2],
        "flipped-late": corrupt(data, len(data) - 100),
        "flipped-mid": corrupt(data, len(data) // 2),
        "header-only": data[:4096],
    }[kind]
    response = httpx.post(f"{server.base_url}/v1/assets?id=bad", content=body, timeout=60)
    assert_error(response, 422, "bad_upload")
    assert_healthy(server, files)
    assert_error(httpx.get(f"{server.base_url}/v1/assets/bad"), 404, "not_found")


@pytest.mark.parametrize(("name", "content", "extra", "kind"), [
    ("cube.off", b"OFF\n8 12 0\n1 2\n", {}, "bad_upload"),
    ("cube.obj", b"v 1 2\nf 1 2 9\n", {}, "bad_upload"),
    ("cube.ply", b"ply\nformat nonsense\n", {}, "bad_upload"),
    ("cube.stl", b"\x00" * 10, {}, "bad_upload"),
    ("cube.glb", b"glTF\x02\x00\x00\x00garbage", {}, "bad_upload"),
    ("cube.gltf", b"{\"asset\": 1}", {}, "bad_upload"),
    ("cube.xyz", CUBE_OFF, {}, "invalid"),
    ("cube.off", CUBE_OFF, {"options": '{"cameras": 13}'}, "invalid"),
    ("cube.off", CUBE_OFF, {"options": '{"resolution": 0}'}, "invalid"),
    ("cube.off", CUBE_OFF, {"options": '{"bogus": 1}'}, "invalid"),
    ("cube.off", CUBE_OFF, {"unknown_field": "1"}, "invalid"),
])
def test_malformed_mesh_upload_is_422(
    server: Server, name: str, content: bytes, extra: dict[str, str], kind: str
) -> None:
    files = server.asset_files()
    response = httpx.post(f"{server.base_url}/v1/bake", files={"mesh": (name, content)},
                          data={"id": "badmesh", **extra}, timeout=60)
    assert_error(response, 422, kind)
    assert_healthy(server, files)
    assert_error(httpx.get(f"{server.base_url}/v1/assets/badmesh"), 404, "not_found")


def test_bake_options_malformed_json_is_400(server: Server) -> None:
    files = server.asset_files()
    response = httpx.post(f"{server.base_url}/v1/bake", files={"mesh": ("c.off", CUBE_OFF)},
                          data={"options": '{"cameras": NaN}'})
    assert_error(response, 400, "malformed_json")
    response = httpx.post(f"{server.base_url}/v1/bake", data={"id": "nomesh"},
                          files={"other": ("x", b"1")})
    assert response.status_code == 422
    assert_healthy(server, files)


# --- path traversal ------------------------------------------------------------------------------

TRAVERSAL_IDS = ["..", "%2e%2e", "..%2F..%2Fetc%2Fpasswd", "..%5Cdemo", ".hidden", "demo.lfa",
                 "a%2Fb", "%00demo", "-lead", "x" * 65, "d%C3%A9mo"]


@pytest.mark.parametrize("bad_id", TRAVERSAL_IDS)
def test_path_traversal_ids_are_422(server: Server, bad_id: str) -> None:
    files = server.asset_files()
    base = server.base_url
    data = (server.assets / "demo.lfa").read_bytes()
    checks = [
        ("GET", f"/v1/assets/{bad_id}", None),
        ("DELETE", f"/v1/assets/{bad_id}", None),
        ("POST", f"/v1/assets/{bad_id}/render", json.dumps({"view": VIEW}).encode()),
        ("GET", f"/v1/jobs/{bad_id}", None),
        ("POST", f"/v1/assets?id={bad_id}", data),
    ]
    for method, path, content in checks:
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=60)
        try:
            conn.request(method, path, body=content,
                         headers={"Content-Type": "application/json"} if content else {})
            response = conn.getresponse()
            body = json.loads(response.read())
        finally:
            conn.close()
        assert response.status == 422, (method, path, response.status, body)
        assert body["error"]["kind"] == "invalid", (method, path, body)
    bake = httpx.post(f"{base}/v1/bake", files={"mesh": ("c.off", CUBE_OFF)},
                      data={"id": bad_id.replace("%2F", "/").replace("%2e", ".")})
    assert_error(bake, 422, "invalid")
    assert_healthy(server, files)
    assert (server.assets / "demo.lfa").is_file()


@pytest.mark.parametrize("path", ["/v1/assets/../../etc/passwd", "/v1/assets/demo/../../x",
                                  "/../../etc/passwd", "/v1/assets/%2e%2e/%2e%2e/etc/passwd"])
def test_raw_dot_segments_never_escape(server: Server, path: str) -> None:
    """Un-normalised dot segments match no route (404) or fail the id check (422)."""
    files = server.asset_files()
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    try:
        conn.request("GET", path)
        response = conn.getresponse()
        body = response.read()
    finally:
        conn.close()
    assert response.status in (404, 422), (path, response.status, body[:200])
    assert json.loads(body)["error"]["kind"] in ("not_found", "invalid")
    assert b"root:" not in body
    assert_healthy(server, files)


# --- shutdown ------------------------------------------------------------------------------------


STALLED_BODIES = [
    ("POST /v1/assets?id=stalled", "application/octet-stream", b"LFA"),
    ("POST /v1/bake", "multipart/form-data; boundary=XX",
     b'--XX\r\nContent-Disposition: form-data; name="mesh"; filename="a.off"\r\n\r\nOFF\n'),
]


@pytest.mark.parametrize(("request_line", "content_type", "start"), STALLED_BODIES,
                         ids=["upload", "bake"])
def test_stalled_upload_and_bake_bodies_are_408(
    tmp_path: Path, demo_lfa: Path, request_line: str, content_type: str, start: bytes
) -> None:
    """A body that stops arriving is 408 (docs/protocol.md), not 400 for an upload or 500 for a
    bake form (the multipart parser's status for a body that failed to arrive)."""
    with running_server(tmp_path, demo_lfa, extra=["--body-timeout-secs", "1"]) as own:
        files = own.asset_files()
        with socket.create_connection(("127.0.0.1", own.port), timeout=10) as sock:
            sock.sendall(f"{request_line} HTTP/1.1\r\nHost: e2e\r\nContent-Type: {content_type}"
                         f"\r\nContent-Length: 100000\r\n\r\n".encode() + start)
            reply = b""
            while b"\r\n\r\n" not in reply or not reply.rstrip().endswith(b"}"):
                chunk = sock.recv(4096)
                if not chunk:
                    break
                reply += chunk
        head, _, body = reply.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 408"), reply
        error = json.loads(body)["error"]
        assert error["kind"] == "rejected" and "stalled" in error["message"], error
        assert own.asset_files() == files
        assert metric(httpx.get(f"{own.base_url}/metrics").text, "lumigraph_errors_total",
                      kind="internal") == 0


def test_sigterm_with_a_stalled_upload_exits_promptly(tmp_path: Path, demo_lfa: Path) -> None:
    with running_server(tmp_path, demo_lfa) as own:
        sock = socket.create_connection(("127.0.0.1", own.port), timeout=30)
        try:
            sock.sendall(b"POST /v1/assets?id=slow HTTP/1.1\r\nHost: e2e\r\n"
                         b"Content-Length: 1000000\r\n\r\n" + b"x" * 1000)
            time.sleep(0.3)
            own.proc.send_signal(signal.SIGTERM)
            try:
                own.proc.wait(timeout=12)
                exited = True
            except subprocess.TimeoutExpired:
                exited = False
        finally:
            sock.close()  # lets the server finish shutting down (running_server checks exit 0)
        assert exited, "SIGTERM did not stop the server within 12 s"
