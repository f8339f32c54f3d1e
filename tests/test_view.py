"""view.html in headless Chromium: the page loads from file:// without any network request,
plays, the rover moves in the picture between two screenshots, a paused page does not change, and the console has
no errors; a 2D run (the main job's) and a 3D run (turn_flat).

Chromium is the Debian package (`apt-get install chromium`; .ci/run installs it when it runs as root with apt-get).
Without it these tests skip and say why. It is driven over the Chrome DevTools Protocol (a websocket, `websockets`
pinned in requirements.txt); it is started headless, without sandbox, GPU, QUIC or any Google service, with a
fresh profile (the closed network refuses Google hosts)."""
from __future__ import annotations

import base64
import io
import json
import os
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
BUILD = REPO / "build"
SIZE = (1000, 650)


def chromium_path() -> str | None:
    return os.environ.get("CEDRA_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")


def _need_browser():
    if not chromium_path():
        pytest.skip("headless-browser test skipped: no Chromium on PATH (the Debian package `chromium`; .ci/run "
                    "installs it with apt-get when it runs as root; set CEDRA_CHROMIUM to use another binary)")
    try:
        import websockets.sync.client  # noqa: F401
    except ImportError:
        pytest.skip("headless-browser test skipped: the websocket client `websockets` is not installed "
                    "(pip install -r requirements.txt)")


class Chromium:
    """A headless Chromium and one page, over the DevTools protocol. Console errors, uncaught exceptions and every
    network request are recorded."""

    def __init__(self, profile: Path):
        from websockets.sync.client import connect
        profile.mkdir(parents=True, exist_ok=True)
        self.log = open(profile / "chromium.log", "w")
        self.proc = subprocess.Popen(
            [chromium_path(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-default-apps", "--disable-dev-shm-usage", "--mute-audio", "--hide-scrollbars",
             f"--user-data-dir={profile}",
             "--remote-debugging-port=0", f"--window-size={SIZE[0]},{SIZE[1]}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=self.log)
        port_file = profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not (port_file.exists() and port_file.read_text().strip()):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise RuntimeError(f"Chromium did not start: {(profile / 'chromium.log').read_text()[-2000:]}")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        pages = []
        while not pages and time.monotonic() < deadline:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                pages = [p for p in json.load(r) if p["type"] == "page"]
            time.sleep(0.05)
        self.ws = connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=30).__enter__()
        self.next_id, self.events = 0, []
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable")
        self.call("Emulation.setDeviceMetricsOverride", width=SIZE[0], height=SIZE[1], deviceScaleFactor=1,
                  mobile=False)

    def call(self, method, **params):
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=60))
            if msg.get("id") == self.next_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            self.events.append(msg)

    def open(self, url: str):
        self.call("Page.navigate", url=url)
        deadline = time.monotonic() + 30
        while not any(e.get("method") == "Page.loadEventFired" for e in self.events):
            if time.monotonic() > deadline:
                raise RuntimeError(f"{url} did not load")
            self.call("Runtime.evaluate", expression="1")      # lets events arrive
            time.sleep(0.05)

    def eval(self, expression):
        r = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression}: {r['exceptionDetails']}")
        return r["result"].get("value")

    def screenshot(self) -> np.ndarray:
        from PIL import Image
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)

    def errors(self) -> list[str]:
        out = []
        for e in self.events:
            m, p = e.get("method"), e.get("params", {})
            if m == "Runtime.exceptionThrown":
                out.append(f"exception: {p['exceptionDetails'].get('exception', {}).get('description', p)}")
            elif m == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                out.append("console.error: " + " ".join(str(a.get("value", a.get("description"))) for a in p["args"]))
            elif m == "Log.entryAdded" and p["entry"]["level"] == "error":
                out.append(f"log: {p['entry']['text']} ({p['entry'].get('url', '')})")
        return out

    def requests(self) -> list[str]:
        return [e["params"]["request"]["url"] for e in self.events if e.get("method") == "Network.requestWillBeSent"]

    def close(self):
        try:
            if getattr(self, "ws", None):
                self.ws.close()
        finally:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.log.close()


@pytest.fixture
def browser(tmp_path):
    _need_browser()
    b = Chromium(tmp_path / "profile")
    yield b
    b.close()


def body_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the body box's orange (232, 137, 43), shaded 0.55..1 (the terrain's browns have far more blue)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 100) & (g < 0.66 * r) & (g > 0.45 * r) & (b < 0.28 * r)


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    """view.html of a 2D run (the main job's loop and outputs, 8 s) and of a 3D run (turn_flat, 6 s): longer than
    the test plays (it loops at the end)."""
    _need_browser()
    from cedra.run import scenario, simulate
    from cedra.run.watch import watch
    out = tmp_path_factory.mktemp("views")
    names, rows, _, info = simulate.run_bump(BUILD / "bump2d.fmu", 8.0)
    assert info["ok"]
    two = watch(out / "bump2d", names, rows, BUILD / "bump2d.fmu", video=False)["view"]
    scenario.load("turn_flat").run(out_dir=str(out / "turn_flat"), build_dir=str(BUILD), stop_time=6.0, quiet=True)
    return {"bump2d": two, "turn_flat": out / "turn_flat" / "view.html"}


@pytest.mark.parametrize("name", ["bump2d", "turn_flat"])
def test_page_plays_and_the_rover_moves(name, pages, browser):
    """Fixed camera (#follow=0): while playing, the body's orange pixels move between two screenshots 1.5 s
    apart; paused, two screenshots 1 s apart are identical; no console errors, no request but the file itself."""
    url = pages[name].resolve().as_uri() + "#follow=0"
    browser.open(url)
    deadline = time.monotonic() + 20
    while not browser.eval("window.cedraView ? window.cedraView.renders : 0"):
        assert time.monotonic() < deadline, "the page never rendered"
        time.sleep(0.1)
    assert browser.eval("cedraView.playing") is True
    time.sleep(0.3)
    t_a, a = browser.eval("cedraView.time"), browser.screenshot()
    time.sleep(1.5)
    t_b, b = browser.eval("cedraView.time"), browser.screenshot()
    assert t_b - t_a > 0.5, (t_a, t_b)
    ma, mb = body_mask(a), body_mask(b)
    assert ma.sum() > 500 and mb.sum() > 500, (ma.sum(), mb.sum())          # the body is in the picture
    ya, xa = np.argwhere(ma).mean(axis=0)
    yb, xb = np.argwhere(mb).mean(axis=0)
    moved = np.hypot(xb - xa, yb - ya)
    changed = int((np.abs(a - b).sum(axis=2) > 30).sum())
    print(f"{name}: t {t_a:.2f} -> {t_b:.2f} s, body moved {moved:.0f} px, {changed} pixels changed")
    assert moved > 15
    assert changed > 2000
    # paused: nothing changes
    browser.eval("document.getElementById('play').click()")
    assert browser.eval("cedraView.playing") is False
    time.sleep(0.3)
    t_c, c = browser.eval("cedraView.time"), browser.screenshot()
    time.sleep(1.0)
    t_d, d = browser.eval("cedraView.time"), browser.screenshot()
    assert t_c == t_d
    assert np.array_equal(c, d)
    # the slider moves the rover too
    browser.eval("var s = document.getElementById('slider'); s.value = 1000; s.dispatchEvent(new Event('input'))")
    time.sleep(0.3)
    assert abs(browser.eval("cedraView.time") - browser.eval("cedraView.t1")) < 1e-6
    e = browser.screenshot()
    assert int((np.abs(e - d).sum(axis=2) > 30).sum()) > 2000
    assert browser.errors() == []
    assert all(u.startswith(("file:", "data:")) for u in browser.requests()), browser.requests()


def test_the_harness_sees_console_errors_and_requests(browser, tmp_path):
    """The checks above can fail: a page with a console error, an exception and a network request is caught."""
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><img src='http://127.0.0.1:9/x.png'><script>console.error('boom');"
                   "undefinedFunction();</script></body></html>")
    browser.open(bad.as_uri())
    time.sleep(0.5)
    browser.eval("1")
    errors = browser.errors()
    assert any("boom" in e for e in errors), errors
    assert any("undefinedFunction" in e for e in errors), errors
    assert any(u.startswith("http://127.0.0.1:9") for u in browser.requests())
