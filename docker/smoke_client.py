"""docker/smoke.sh's client: one frame over HTTP and one over the WebSocket stream from a
running service, checked. Usage: python smoke_client.py BASE_URL ASSET_ID"""

from __future__ import annotations

import asyncio
import json
import struct
import sys
import urllib.request

from websockets.asyncio.client import connect

VIEW = {"eye": [0.5, 0.6, 3.0], "target": [0, 0, 0], "up": [0, 1, 0], "yfov_deg": 40, "width": 160,
        "height": 120}  # fmt: skip
PNG = b"\x89PNG\r\n\x1a\n"


def http_frame(base: str, asset: str) -> int:
    body = json.dumps({"view": VIEW, "format": "png"}).encode()
    request = urllib.request.Request(f"{base}/v1/assets/{asset}/render", data=body,
                                     headers={"Content-Type": "application/json"})  # fmt: skip
    with urllib.request.urlopen(request, timeout=120) as response:
        png = response.read()
        assert response.status == 200 and png.startswith(PNG), response.status
        width, height = struct.unpack(">II", png[16:24])
        assert (width, height) == (160, 120), (width, height)
        return len(png)


async def stream_frame(base: str, asset: str) -> int:
    async with connect(base.replace("http", "ws", 1) + f"/v1/stream?asset={asset}", max_size=1 << 26) as ws:
        hello = json.loads(await ws.recv())
        assert hello["type"] == "hello", hello
        await ws.send(json.dumps({"type": "settings", "interactive": False, "still_codec": "png"}))
        await ws.send(json.dumps({"type": "view", "id": 7, "view": VIEW, "still": True}))
        while True:
            message = await asyncio.wait_for(ws.recv(), 120)
            assert isinstance(message, bytes), message
            magic, header_len = struct.unpack_from("<4sH", message)
            request_id, width, height = struct.unpack_from("<III", message, 12)
            assert magic == b"LGF1", magic
            if request_id == 7:
                assert (width, height) == (160, 120) and message[header_len:].startswith(PNG)
                return len(message)


def main() -> None:
    base, asset = sys.argv[1], sys.argv[2]
    http_bytes = http_frame(base, asset)
    stream_bytes = asyncio.run(stream_frame(base, asset))
    print(json.dumps({"http_png_bytes": http_bytes, "stream_frame_bytes": stream_bytes}))


if __name__ == "__main__":
    main()
