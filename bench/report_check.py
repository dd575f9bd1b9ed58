"""Open QA reports in a real headless Chromium and check what a reader gets.

For each ``.html`` given (or found under a directory): the page loads with no
console error, no uncaught exception and no failed resource; every
``<video>`` reports a finite duration > 0, no media error, and plays (its
current time advances); a screenshot of the whole page is written beside the
report (``<name>.screenshot.png``) to look at.

Chromium (Debian's ``chromium``; ``make report-check`` installs it) is driven
through the DevTools protocol over a pipe (``--remote-debugging-pipe``:
JSON messages separated by NUL bytes on file descriptors 3 and 4), with the
standard library only.

Usage: ``python bench/report_check.py [--chromium PATH] FILE_OR_DIR...``;
exits 1 if any check fails.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Flags Chromium needs on these machines (no network, no GPU, run as root).
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--mute-audio", "--autoplay-policy=no-user-gesture-required",
         "--remote-debugging-pipe")
#: Width of the screenshot (the report's max-width and margins).
WIDTH = 1480
#: JavaScript: every video's metadata, then a short play; resolves to a list.
VIDEO_PROBE = """
(async () => {
  const wait = (v, event, ms) => new Promise(done => {
    const t = setTimeout(() => done(false), ms);
    v.addEventListener(event, () => { clearTimeout(t); done(true); }, {once: true});
    v.addEventListener('error', () => { clearTimeout(t); done(false); }, {once: true});
  });
  const out = [];
  for (const v of document.querySelectorAll('video')) {
    if (v.readyState < 1) await wait(v, 'loadedmetadata', 20000);
    const info = {duration: v.duration, error: v.error ? v.error.code : null,
                  message: v.error ? v.error.message : null, width: v.videoWidth,
                  height: v.videoHeight, played: 0};
    if (!v.error) {
      v.muted = true;
      try { await v.play(); } catch (e) { info.message = String(e); }
      await new Promise(done => setTimeout(done, 1500));
      info.played = v.currentTime;
      v.pause();
    }
    info.error = v.error ? v.error.code : info.error;
    out.push(info);
  }
  return out;
})()
"""


class DevTools:
    """A Chromium process and its DevTools protocol over a pipe."""

    def __init__(self, chromium: str):
        self.profile = tempfile.mkdtemp(prefix="report-check-")
        to_child_r, self._write = os.pipe()
        self._read, from_child_w = os.pipe()
        def as_fds_3_and_4():
            # Chromium reads commands on fd 3 and writes replies on fd 4 (copies first:
            # either pipe end may already be 3 or 4).
            commands, replies = os.dup(to_child_r), os.dup(from_child_w)
            os.dup2(commands, 3)
            os.dup2(replies, 4)

        self.process = subprocess.Popen(
            [chromium, *FLAGS, f"--user-data-dir={self.profile}", f"--window-size={WIDTH},900"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            pass_fds=(3, 4), preexec_fn=as_fds_3_and_4)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buffer, self._id, self.events = b"", 0, []

    def _message(self, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        while b"\0" not in self._buffer:
            if time.monotonic() > deadline:
                raise TimeoutError("Chromium did not answer")
            chunk = os.read(self._read, 1 << 20)
            if not chunk:
                raise RuntimeError("Chromium closed the DevTools pipe")
            self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(raw)

    def send(self, method: str, params: dict | None = None, *, session: str | None = None,
             timeout: float = 60.0) -> dict:
        """Send a command and return its result (events met meanwhile are kept)."""
        self._id += 1
        message = {"id": self._id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        while True:
            reply = self._message(timeout)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_event(self, method: str, timeout: float = 60.0) -> dict:
        """The first event `method` (already received, or the next ones)."""
        for event in self.events:
            if event.get("method") == method:
                return event
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            event = self._message(deadline - time.monotonic())
            self.events.append(event)
            if event.get("method") == method:
                return event
        raise TimeoutError(f"no {method} within {timeout:g} s")

    def close(self) -> None:
        try:
            self.send("Browser.close", timeout=10)
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
        os.close(self._read)
        os.close(self._write)
        shutil.rmtree(self.profile, ignore_errors=True)


def problems_in(events) -> list:
    """Console errors, uncaught exceptions and failed loads among DevTools events."""
    found = []
    for event in events:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            found.append("console: " + " ".join(str(a.get("value", a.get("description", "")))
                                                for a in params.get("args", [])))
        elif method == "Runtime.exceptionThrown":
            found.append("exception: " + params["exceptionDetails"].get("text", ""))
        elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
            found.append(f"log: {params['entry'].get('text', '')}")
        elif method == "Network.loadingFailed" and not params.get("canceled"):
            found.append(f"load failed: {params.get('errorText', '')}")
    return found


def check(path: Path, chromium: str) -> bool:
    tools = DevTools(chromium)
    try:
        (target,) = [t for t in tools.send("Target.getTargets")["targetInfos"]
                     if t["type"] == "page"][:1]
        session = tools.send("Target.attachToTarget", {"targetId": target["targetId"],
                                                       "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            tools.send(f"{domain}.enable", session=session)
        tic = time.perf_counter()
        tools.send("Page.navigate", {"url": path.resolve().as_uri()}, session=session)
        tools.wait_event("Page.loadEventFired", timeout=120)
        loaded = time.perf_counter() - tic
        videos = tools.send("Runtime.evaluate", {"expression": VIDEO_PROBE,
                                                 "awaitPromise": True, "returnByValue": True},
                            session=session, timeout=120)["result"].get("value", [])
        size = tools.send("Page.getLayoutMetrics", session=session)["cssContentSize"]
        height = int(min(size["height"], 16000))
        tools.send("Emulation.setDeviceMetricsOverride",
                   {"width": WIDTH, "height": height, "deviceScaleFactor": 1, "mobile": False},
                   session=session)
        shot = tools.send("Page.captureScreenshot", {"format": "png",
                                                     "captureBeyondViewport": True},
                          session=session, timeout=120)
        picture = path.with_name(path.stem + ".screenshot.png")
        picture.write_bytes(base64.b64decode(shot["data"]))
        issues = problems_in(tools.events)
        version = tools.send("Browser.getVersion").get("product", "Chromium")
    finally:
        tools.close()
    print(f"{path}: {version}, loaded in {loaded:.1f} s, page {WIDTH}x{size['height']:.0f} px, "
          f"screenshot {picture.name}")
    ok = not issues
    print(f"  {'ok  ' if not issues else 'FAIL'} console errors, exceptions, failed loads: "
          f"{len(issues)}" + "".join(f"\n       {i}" for i in issues[:10]))
    if not videos:
        print("  ok   no <video> on the page")
    for k, v in enumerate(videos, start=1):
        duration = v.get("duration")
        good = (v.get("error") is None and isinstance(duration, (int, float))
                and 0 < duration < float("inf") and v.get("played", 0) > 0)
        ok &= good
        print(f"  {'ok  ' if good else 'FAIL'} video {k}: duration {duration} s, "
              f"{v.get('width')}x{v.get('height')}, error {v.get('error')}"
              f"{' (' + v['message'] + ')' if v.get('message') else ''}, played to "
              f"{v.get('played', 0):.2f} s")
    return ok


def main(argv) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="+", type=Path)
    parser.add_argument("--chromium", default=shutil.which("chromium") or "/usr/bin/chromium")
    args = parser.parse_args(argv)
    if not Path(args.chromium).exists():
        print(f"{args.chromium}: no Chromium (make report-check installs Debian's)",
              file=sys.stderr)
        return 2
    pages = []
    for p in args.paths:
        pages += sorted(q for q in p.rglob("*.html")) if p.is_dir() else [p]
    if not pages:
        print("no .html reports given or found", file=sys.stderr)
        return 2
    results = [check(p, args.chromium) for p in pages]
    print(f"{sum(results)} of {len(results)} reports load and play in Chromium")
    return 0 if all(results) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
