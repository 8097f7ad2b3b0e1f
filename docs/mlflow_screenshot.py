"""docs/mlflow_ui.png: the MLflow UI in a real (headless) browser, against the workflow's store.

    .venv/bin/python docs/mlflow_screenshot.py [OUT.png] [--store sqlite:///results/mlflow.db]
    make mlflow-screenshot

Starts ``mlflow ui`` as ``make mlflow-ui`` does (127.0.0.1, one worker, job execution off) on a free
port, drives Debian's Chromium (``apt-get install chromium``) through the DevTools protocol
(aiohttp, which MLflow already brings), as a user goes: the address `make mlflow-ui` prints (the
experiment list, in MLflow's model-training mode), then the link that leads the learning experiment's
description, which opens its runs with their results (RMSE, ratio to the nominal model, inputs); the
user's two clicks: the assistant panel closed, the sweeps expanded into their jobs.  No column is
picked by hand: the results view is qr's (qr.tracking).  The two views are stacked into one PNG,
reduced to a palette to stay small.  The server and the browser are stopped afterwards (their whole
process groups), also on errors.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars", "--window-size=1440,900"]


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def wait_http(url: str, what: str, timeout_s: float = 120):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                return r.read()
        except OSError:
            time.sleep(0.3)
    raise SystemExit(f"mlflow_screenshot: {what} did not answer at {url}")


def stop(proc: subprocess.Popen) -> None:
    """SIGTERM to the process group (a server's workers too), SIGKILL if it lingers."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    except ProcessLookupError:
        pass


class Page:
    """The few DevTools-protocol calls we need, over aiohttp's websocket client."""

    def __init__(self, ws):
        self.ws, self.n = ws, 0

    async def call(self, method, **params):
        self.n += 1
        await self.ws.send_json({"id": self.n, "method": method, "params": params})
        while True:
            msg = await self.ws.receive_json()
            if msg.get("id") == self.n:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    async def js(self, expr):
        r = await self.call("Runtime.evaluate", expression=expr, awaitPromise=True, returnByValue=True)
        return r.get("result", {}).get("value")

    async def until(self, expr, what, timeout_s=60):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if await self.js(f"!!({expr})"):
                return
            await asyncio.sleep(0.3)
        raise SystemExit(f"mlflow_screenshot: the page never showed {what}")

    async def goto(self, url, ready_expr, what):
        await self.call("Page.navigate", url=url)
        await self.until(ready_expr, what)
        await asyncio.sleep(1.5)  # let the table settle

    async def png(self) -> bytes:
        return base64.b64decode((await self.call("Page.captureScreenshot", format="png"))["data"])


CLICK_TEXT = """(() => {{ const el = Array.from(document.querySelectorAll('{scope}')).find(
    e => e.childElementCount === 0 && e.innerText && e.innerText.trim() === {text!r}); if (el) el.click(); return !!el; }})()"""


async def capture(base: str, experiment_id: str, chromium_port: int) -> list[bytes]:
    import aiohttp

    from qr.tracking import UI_QUERY

    tabs = json.loads(wait_http(f"http://127.0.0.1:{chromium_port}/json/list", "Chromium"))
    ws_url = next(t for t in tabs if t["type"] == "page")["webSocketDebuggerUrl"]
    async with aiohttp.ClientSession() as session, session.ws_connect(ws_url, max_msg_size=0) as ws:
        page = Page(ws)
        await page.call("Page.enable")
        await page.call("Runtime.enable")
        # the experiment list: one experiment per stage
        await page.goto(f"{base}/#/experiments?{UI_QUERY}", "document.body.innerText.includes('qr-learn')",
                        "the experiments")
        experiments = await page.png()
        # the learning experiment's page; its description's first link opens the runs with their results
        # (in a new tab: followed here in this one)
        await page.goto(f"{base}/#/experiments/{experiment_id}/runs?{UI_QUERY}",
                        "document.body.innerText.includes('matching runs')", "the runs table")
        link = await page.js("(Array.from(document.querySelectorAll('a')).find(a => a.innerText.includes("
                             "'Runs with their results')) || {}).href")
        if not link:
            raise SystemExit("mlflow_screenshot: the experiment's description has no link to its results view")
        await page.call("Page.navigate", url="about:blank")
        await page.goto(link, "document.body.innerText.includes('matching runs')", "the results view")
        await page.js("(() => { const b = document.querySelector('button[aria-label=Close]'); if (b) b.click(); })()")
        await asyncio.sleep(1)
        await page.js("Array.from(document.querySelectorAll('[role=row] button.du-bois-light-btn-link'))"
                      ".forEach(b => b.click())")  # expand every sweep into its jobs
        await asyncio.sleep(3)
        runs = await page.png()
    return [experiments, runs]


def compose(shots: list[bytes], out: Path, crop_first: int = 480) -> None:
    from PIL import Image

    imgs = [Image.open(io.BytesIO(b)).convert("RGB") for b in shots]
    imgs[0] = imgs[0].crop((0, 0, imgs[0].width, min(crop_first, imgs[0].height)))
    sheet = Image.new("RGB", (max(i.width for i in imgs), sum(i.height for i in imgs) + 8), "white")
    y = 0
    for img in imgs:
        sheet.paste(img, (0, y))
        y += img.height + 8
    sheet = sheet.quantize(colors=128, method=Image.Quantize.MEDIANCUT)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.png")
    sheet.save(tmp, optimize=True)
    os.replace(tmp, out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", nargs="?", default=str(ROOT / "docs" / "mlflow_ui.png"))
    ap.add_argument("--store", default=f"sqlite:///{ROOT / 'results' / 'mlflow.db'}")
    ap.add_argument("--experiment", default="qr-learn")
    a = ap.parse_args(argv)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if not chromium:
        raise SystemExit("mlflow_screenshot: no chromium; install Debian's: apt-get install -y chromium")
    port, cport = free_port(), free_port()
    mlflow = str(Path(sys.executable).with_name("mlflow"))
    server = subprocess.Popen([mlflow, "ui", "--backend-store-uri", a.store, "--host", "127.0.0.1", "--port", str(port),
                               "--workers", "1"], env={**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"},
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    profile = tempfile.mkdtemp(prefix="qr-chromium-")
    browser = None
    try:
        base = f"http://127.0.0.1:{port}"
        wait_http(f"{base}/health", "mlflow ui")
        req = urllib.request.Request(f"{base}/ajax-api/2.0/mlflow/experiments/get-by-name?experiment_name={a.experiment}")
        experiment_id = json.loads(urllib.request.urlopen(req).read())["experiment"]["experiment_id"]
        browser = subprocess.Popen([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                                    f"--remote-debugging-port={cport}", "about:blank"],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        shots = asyncio.run(capture(base, experiment_id, cport))
        compose(shots, Path(a.out))
    finally:
        if browser is not None:
            stop(browser)
        stop(server)
        shutil.rmtree(profile, ignore_errors=True)
    print(f"{a.out}: {Path(a.out).stat().st_size // 1024} KB")


if __name__ == "__main__":
    main()
