"""Screenshot of a web page that needs real seconds to start (Rerun's web viewer compiles its
WebAssembly first, which ``chromium --screenshot --virtual-time-budget`` does not wait for):
headless Chromium driven over the DevTools protocol, shot after ``--wait`` seconds.

    rerun --serve-web --web-viewer-port 9090 --port 9876 run.rrd &
    PROXY='rerun%2Bhttp%3A%2F%2Flocalhost%3A9876%2Fproxy'
    python tools/viewer_screenshot.py --url "http://127.0.0.1:9090/?url=$PROXY" \
        --out docs/img/rerun_dynamic.png --wait 40

Needs Debian's ``chromium`` and ``aiohttp`` (installed with the dev tools); reaches nothing but
the local URL.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]  # fmt: skip


async def shoot(port: int, url: str, out: Path, wait: float, size: tuple[int, int]) -> None:
    import aiohttp

    for _ in range(50):  # the browser's endpoint comes up within a few seconds
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list") as r:
                pages = [p for p in json.load(r) if p["type"] == "page"]
            break
        except OSError:
            time.sleep(0.2)
    async with aiohttp.ClientSession() as s, s.ws_connect(pages[0]["webSocketDebuggerUrl"],
                                                          max_msg_size=0) as ws:  # fmt: skip
        ids = iter(range(1, 1000))

        async def call(method: str, **params: object) -> dict:
            n = next(ids)
            await ws.send_json({"id": n, "method": method, "params": params})
            async for msg in ws:
                data = json.loads(msg.data)
                if data.get("id") == n:
                    return data.get("result", {})
            raise RuntimeError("browser closed the connection")

        w, h = size
        await call("Emulation.setDeviceMetricsOverride", width=w, height=h,
                   deviceScaleFactor=1, mobile=False)  # fmt: skip
        await call("Page.navigate", url=url)
        await asyncio.sleep(wait)
        shot = await call("Page.captureScreenshot", format="png")
        out.write_bytes(base64.b64decode(shot["data"]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--url", required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--wait", type=float, default=40.0, help="seconds before the shot")
    ap.add_argument("--size", type=int, nargs=2, default=(1600, 1000), metavar=("W", "H"))
    ap.add_argument("--port", type=int, default=9222, help="DevTools port")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as profile:
        cmd = ["chromium", *FLAGS, f"--user-data-dir={profile}",
               f"--remote-debugging-port={a.port}", f"--window-size={a.size[0]},{a.size[1]}",
               "about:blank"]  # fmt: skip
        browser = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            asyncio.run(shoot(a.port, a.url, a.out, a.wait, tuple(a.size)))
        finally:
            browser.terminate()
            browser.wait(10)
    print(f"{a.out}: {a.out.stat().st_size} bytes")


if __name__ == "__main__":
    main()
