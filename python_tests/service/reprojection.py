"""Helpers for measuring the web viewer's reprojection (test_viewer.py, scripts/bench_reproject.py):
a loopback TCP proxy that delays traffic, and page-side probes of motion-to-photon delay and of
the warped frame's error against the true frame."""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
from collections.abc import Iterator
from typing import Any

from playwright.sync_api import Page


class DelayProxy:
    """A TCP proxy on 127.0.0.1 that holds every chunk for `delay_s` before passing it on, in each
    direction (as `tc netem delay` on the loopback interface would: a round trip gains twice the
    delay). Order is kept and bandwidth is not limited. Runs its own event loop in a thread."""

    def __init__(self, upstream_port: int, delay_s: float) -> None:
        self.upstream_port = upstream_port
        self.delay_s = delay_s
        self.port = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._server: asyncio.Server | None = None

    def __enter__(self) -> DelayProxy:
        self._thread.start()
        self._server = asyncio.run_coroutine_threadsafe(self._start(), self._loop).result(10)
        self.port = int(self._server.sockets[0].getsockname()[1])
        return self

    def __exit__(self, *exc: object) -> None:
        async def stop() -> None:
            if self._server is not None:
                self._server.close()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await asyncio.sleep(0)  # let the transports finish closing

        asyncio.run_coroutine_threadsafe(stop(), self._loop).result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    async def _start(self) -> asyncio.Server:
        return await asyncio.start_server(self._client, "127.0.0.1", 0)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        # A connection handler ends quietly when the proxy stops (asyncio logs a cancelled one).
        with contextlib.suppress(asyncio.CancelledError):
            await self._relay(reader, writer)

    async def _relay(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.upstream_port)
        except OSError:
            writer.close()
            return
        pipes = [asyncio.ensure_future(self._pipe(reader, up_writer)),
                 asyncio.ensure_future(self._pipe(up_reader, writer))]
        try:
            await asyncio.wait(pipes)
        finally:
            for pipe in pipes:
                pipe.cancel()
            await asyncio.gather(*pipes, return_exceptions=True)
            # A pipe cancelled before it started has not closed its writer.
            for w in (writer, up_writer):
                w.close()
                with contextlib.suppress(OSError, asyncio.CancelledError):
                    await w.wait_closed()

    async def _pipe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """Copies reader to writer, each chunk `delay_s` after it was read, in order."""
        queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

        async def deliver() -> None:
            while True:
                due, data = await queue.get()
                wait = due - time.monotonic()
                if wait > 0:
                    await asyncio.sleep(wait)
                if not data:
                    return
                writer.write(data)
                await writer.drain()

        sender = asyncio.ensure_future(deliver())
        try:
            while not sender.done():
                data = await reader.read(1 << 16)
                queue.put_nowait((time.monotonic() + self.delay_s, data))
                if not data:
                    break
            await sender
        except OSError:
            pass
        finally:
            sender.cancel()
            await asyncio.gather(sender, return_exceptions=True)
            writer.close()


@contextlib.contextmanager
def delayed(upstream_port: int, delay_ms: float) -> Iterator[DelayProxy]:
    with DelayProxy(upstream_port, delay_ms / 1000) as proxy:
        yield proxy


# Waits for the newest full-quality frame of the current request to be drawn (after the rest).
SETTLED = ("window.lumigraphViewer.last && window.lumigraphViewer.last.quality === 1"
           " && window.lumigraphViewer.last.requestId === window.lumigraphViewer.requestId")

# Orbits the camera by `dAz` radians about the target, as a drag does; returns the change's
# sequence number and time.
ORBIT = """(dAz) => {
  const v = window.lumigraphViewer;
  v.orbit(dAz);
  const c = v.changes[v.changes.length - 1];
  return {seq: c.seq, t: c.t};
}"""

# The first draw (warped or true) that shows camera `seq` or a later one, if any yet.
FIRST_DRAW = """(seq) => {
  const d = window.lumigraphViewer.draws.find((e) => e.seq >= seq);
  return d ? {kind: d.kind, t: d.t} : null;
}"""

# Draws the kept frames reprojected to the camera orbited by `dAz` radians (nothing is sent),
# renders the true frame for that camera over HTTP and compares them (DESIGN §3 masked PSNR:
# 8-bit RGB, data range 255, over the union of both coverage masks, colour outside coverage
# black). Also compares the frame the viewer would show without reprojection (the kept frame
# stretched unchanged) with the true frame. Hole pixels: covered in the true frame, not covered
# by the warp.
MEASURE_WARP = """async (dAz) => {
  const v = window.lumigraphViewer;
  const source = v.currentView();
  v.azimuth += dAz;
  const view = v.currentView();
  if (!v.drawWarped()) throw new Error('nothing to warp');
  const pixels = (image, w, h) => {
    const c = document.createElement('canvas');
    c.width = w; c.height = h;
    const ctx = c.getContext('2d');
    ctx.drawImage(image, 0, 0, w, h);
    return ctx.getImageData(0, 0, w, h).data;
  };
  const render = async (vw) => {
    const res = await fetch(`/v1/assets/${v.asset.id}/render`, {method: 'POST',
      headers: {'content-type': 'application/json'},
      body: JSON.stringify({view: vw, format: 'png', background: [0, 0, 0, 0]})});
    if (!res.ok) throw new Error(`render: ${res.status} ${await res.text()}`);
    const bitmap = await createImageBitmap(await res.blob(),
      {premultiplyAlpha: 'none', colorSpaceConversion: 'none'});
    return pixels(bitmap, vw.width, vw.height);
  };
  const w = view.width, h = view.height;
  const warped = pixels(v.warpCanvas, w, h);
  const truth = await render(view);
  const stale = await render(source);
  const compare = (a, b) => {
    let sum = 0, union = 0, holes = 0, mismatch = 0;
    for (let i = 0; i < w * h; i++) {
      const ca = a[4 * i + 3] > 0, cb = b[4 * i + 3] > 0;
      if (ca !== cb) mismatch++;
      if (cb && !ca) holes++;
      if (!ca && !cb) continue;
      union++;
      for (let k = 0; k < 3; k++) {
        const e = (ca ? a[4 * i + k] : 0) - (cb ? b[4 * i + k] : 0);
        sum += e * e;
      }
    }
    const mse = sum / Math.max(1, 3 * union);
    return {psnr: mse > 0 ? 10 * Math.log10(255 * 255 / mse) : Infinity, holes, mismatch,
            covered: union};
  };
  v.azimuth -= dAz;
  return {width: w, height: h, warp: compare(warped, truth), stale: compare(stale, truth)};
}"""


def orbit(page: Page, d_azimuth: float) -> dict[str, float]:
    result: dict[str, float] = page.evaluate(ORBIT, d_azimuth)
    return result


def motion_to_photon(page: Page, d_azimuth: float, timeout_ms: float = 30_000) -> dict[str, Any]:
    """Orbits by `d_azimuth` and returns {kind, ms}: which draw first showed the new camera and
    how long after the change (page clock)."""
    change = orbit(page, d_azimuth)
    page.wait_for_function(f"({FIRST_DRAW})({int(change['seq'])}) !== null", timeout=timeout_ms)
    first: dict[str, Any] = page.evaluate(FIRST_DRAW, change["seq"])
    return {"kind": first["kind"], "ms": first["t"] - change["t"]}


def measure_warp(page: Page, d_azimuth: float) -> dict[str, Any]:
    result: dict[str, Any] = page.evaluate(MEASURE_WARP, d_azimuth)
    return result
