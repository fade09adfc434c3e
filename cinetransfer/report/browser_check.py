"""Does a report play in a real browser? Opens report.html in headless Chromium (offline: the
network is emulated off and every request the page makes is recorded), and waits until the
side-by-side video has data for the current frame (`readyState >= 2`).

    python -m cinetransfer.report.browser_check OUTDIR/report.html [--chromium PATH]

prints a JSON verdict (readyState, duration, expected duration, requests) and exits 0 when the
video plays with the expected duration (±1 frame), non-zero otherwise. Talks to Chromium over the
DevTools protocol on 127.0.0.1 (a WebSocket; the `websockets` package of the test extra).
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--mute-audio",
         "--autoplay-policy=no-user-gesture-required", "--remote-debugging-address=127.0.0.1",
         "--remote-debugging-port=0")
STATE_JS = """(() => { const v = document.querySelector('video#side-by-side');
  if (!v) return JSON.stringify(null);
  if (v.paused) { v.play().catch(() => {}); }
  return JSON.stringify({readyState: v.readyState, duration: v.duration, error: v.error ? v.error.code : null,
                         width: v.videoWidth, height: v.videoHeight, expected: parseFloat(v.dataset.duration),
                         frames: parseInt(v.dataset.frames), title: document.title}); })()"""


class BrowserError(RuntimeError):
    """Chromium could not be started or driven."""


def find_chromium(given: str | None = None) -> str:
    for c in (given, "chromium", "chromium-browser", "google-chrome"):
        if c and (shutil.which(c) or Path(c).is_file()):
            return shutil.which(c) or c
    raise BrowserError("no Chromium found (Debian: apt-get install -y chromium)")


class _Cdp:
    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.n = 0
        self.events: list[dict[str, Any]] = []

    def call(self, method: str, params: dict | None = None, session: str | None = None,
             timeout: float = 60.0) -> dict[str, Any]:
        self.n += 1
        msg: dict[str, Any] = {"id": self.n, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        self.ws.send(json.dumps(msg))
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError(f"no answer to {method} within {timeout:.0f} s")
            reply = json.loads(self.ws.recv(timeout=left))
            if reply.get("id") == self.n:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)



def check(page: Path, *, chromium: str | None = None, timeout_s: float = 120.0) -> dict[str, Any]:
    """Open `page` offline in headless Chromium; the video's state once it has data (or at timeout)."""
    from websockets.sync.client import connect

    exe = find_chromium(chromium)
    with tempfile.TemporaryDirectory(prefix="ct-chromium-") as profile:
        proc = subprocess.Popen([exe, *FLAGS, f"--user-data-dir={profile}", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            port_file = Path(profile) / "DevToolsActivePort"
            deadline = time.monotonic() + timeout_s
            while not (port_file.is_file() and len(port_file.read_text().splitlines()) >= 2):
                if proc.poll() is not None:
                    raise BrowserError(f"chromium exited ({proc.returncode}): {proc.stderr.read().decode()[-2000:]}")
                if time.monotonic() > deadline:
                    raise BrowserError("chromium did not open its DevTools port")
                time.sleep(0.1)
            port, path = port_file.read_text().splitlines()[:2]
            with connect(f"ws://127.0.0.1:{port}{path}", max_size=None, open_timeout=30) as ws:
                return _drive(_Cdp(ws), page, deadline)
        finally:
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            if proc.stderr:
                proc.stderr.close()


def _drive(cdp: _Cdp, page: Path, deadline: float) -> dict[str, Any]:
    target = cdp.call("Target.createTarget", {"url": "about:blank"})["targetId"]
    sid = cdp.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
    cdp.call("Network.enable", session=sid)
    cdp.call("Network.emulateNetworkConditions", {"offline": True, "latency": 0, "downloadThroughput": -1,
                                                  "uploadThroughput": -1}, session=sid)
    cdp.call("Page.enable", session=sid)
    cdp.call("Page.navigate", {"url": page.resolve().as_uri()}, session=sid)
    state: dict[str, Any] | None = None
    while time.monotonic() < deadline:
        r = cdp.call("Runtime.evaluate", {"expression": STATE_JS, "returnByValue": True}, session=sid)
        state = json.loads(r.get("result", {}).get("value") or "null")
        if state and (state["readyState"] >= 2 or state["error"]):
            break
        time.sleep(0.2)
    requests = sorted({e["params"]["request"]["url"][:80] for e in cdp.events
                       if e.get("method") == "Network.requestWillBeSent"})
    failed = [e["params"].get("errorText") for e in cdp.events if e.get("method") == "Network.loadingFailed"]
    try:
        cdp.call("Browser.close", timeout=10)
    except Exception:  # noqa: BLE001 - the browser may drop the connection as it closes
        pass
    return {"page": str(page), "video": state, "requests": requests, "failed_requests": failed}


def verdict(result: dict[str, Any]) -> list[str]:
    """What is wrong with a check() result ([] = the page loads offline and the video plays)."""
    v = result.get("video")
    if not v:
        return ["the page has no side-by-side video (or did not load)"]
    problems = []
    if v["error"]:
        problems.append(f"the video failed to decode (MediaError code {v['error']})")
    if v["readyState"] < 2:
        problems.append(f"the video never had data (readyState {v['readyState']})")
    exp, frames = v.get("expected"), v.get("frames") or 1
    if not (v["duration"] and exp and abs(v["duration"] - exp) <= exp / frames + 1e-3):
        problems.append(f"duration {v['duration']} s, expected {exp} s")
    remote = [u for u in result["requests"] if not u.startswith(("file:", "data:"))]
    if remote:
        problems.append(f"the page asked the network for {remote}")
    return problems


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m cinetransfer.report.browser_check", description=__doc__.splitlines()[0])
    p.add_argument("page", help="report.html")
    p.add_argument("--chromium", help="Chromium executable (default: chromium on PATH)")
    p.add_argument("--timeout", type=float, default=120.0)
    args = p.parse_args(argv)
    try:
        result = check(Path(args.page), chromium=args.chromium, timeout_s=args.timeout)
    except BrowserError as e:
        print(f"browser_check: {e}", file=sys.stderr)
        return 2
    result["problems"] = verdict(result)
    print(json.dumps(result, indent=1))
    return 1 if result["problems"] else 0


if __name__ == "__main__":
    sys.exit(main())
