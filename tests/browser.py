"""Headless Chromium for the tests of the pages the project writes or serves (Debian's ``chromium``,
as ``.ci/run`` installs it).

:data:`CHROMIUM` is the browser (``None`` when absent: the tests skip), :func:`chromium_command` its
command line with the flags every test uses, and :class:`Browser` a browser driven through the
DevTools protocol over a pipe (``--remote-debugging-pipe``: JSON messages separated by NUL bytes on
file descriptors 3 and 4), for pages a test must operate: open, wait, run script, take screenshots.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import time
from pathlib import Path

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
#: Flags of every headless run: no sandbox (root in CI), no GPU, nothing fetched besides the page.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", "--no-first-run", "--disable-quic", "--hide-scrollbars")


def chromium_command(profile: Path, *extra: str) -> list[str]:
    """Chromium's command line with :data:`FLAGS`, a fresh profile folder and ``extra`` arguments."""
    return [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *extra]


class BrowserError(AssertionError):
    """The page or the protocol failed (a script threw, a wait ran out)."""


class Browser:
    """One headless Chromium with one page ``width × height`` CSS pixels (device scale 1)."""

    def __init__(self, profile: Path, width: int = 1400, height: int = 1000) -> None:
        to_browser, self._commands = os.pipe()
        self._answers, from_browser = os.pipe()
        command = chromium_command(profile, "--remote-debugging-pipe", "about:blank")
        # the protocol reads fd 3 and writes fd 4 of the browser process
        self.process = subprocess.Popen(
            ["bash", "-c", f'exec "$@" 3<&{to_browser} 4>&{from_browser}', "chromium", *command],
            pass_fds=(to_browser, from_browser), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_browser)
        os.close(from_browser)
        self._buffer = b""
        self._next_id = 0
        self.events: list[dict] = []
        target = self._call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self._session = self._call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for method in ("Page.enable", "Runtime.enable"):
            self.call(method)
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})

    # ------------------------------------------------------------------ protocol

    def _call(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 60.0) -> dict:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        os.write(self._commands, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            answer = self._read(deadline, method)
            if answer.get("id") == self._next_id:
                if "error" in answer:
                    raise BrowserError(f"{method}: {answer['error']}")
                return answer.get("result", {})
            self.events.append(answer)

    def _read(self, deadline: float, method: str) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._answers], [], [], left)[0]:
                raise BrowserError(f"{method}: no answer from the browser in time")
            chunk = os.read(self._answers, 1 << 20)
            if not chunk:
                raise BrowserError(f"{method}: the browser closed the pipe")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def call(self, method: str, params: dict | None = None, timeout: float = 60.0) -> dict:
        """One protocol command on the page; its result."""
        return self._call(method, params, self._session, timeout)

    # ------------------------------------------------------------------ page

    def open(self, url: str) -> None:
        self.call("Page.navigate", {"url": url})

    def evaluate(self, expression: str, timeout: float = 60.0):
        """The value of a script in the page (promises awaited); :class:`BrowserError` if it throws."""
        result = self.call("Runtime.evaluate", {"expression": expression, "awaitPromise": True,
                                                "returnByValue": True}, timeout)
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            raise BrowserError(details.get("exception", {}).get("description") or details.get("text"))
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 60.0, poll_s: float = 0.05):
        """Wait until a script's value is truthy; that value."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(poll_s)
        raise BrowserError(f"waited {timeout:g} s for {expression}")

    def drag_slider(self, selector: str, value: float, steps: int = 6) -> float:
        """Drag the thumb of the range input ``selector`` with the mouse, as a person does, towards
        ``value`` in ``steps`` moves (one ``input`` event each; scrolled to first if off screen); the
        value it reached."""
        box = self.evaluate(f"(() => {{ const e = document.querySelector({json.dumps(selector)}); "
                            "let r = e.getBoundingClientRect(); if (r.top < 0 || r.bottom > innerHeight) "
                            "{ e.scrollIntoView({block: 'center'}); r = e.getBoundingClientRect(); } "
                            "return [r.left, r.top + r.height / 2, r.width, +e.min, +e.max, +e.value]; })()")
        left, y, width, low, high, start = box
        thumb = 16.0  # Chromium's thumb: its centre runs from left + 8 to right - 8 px

        def x_of(v):
            return left + thumb / 2 + (v - low) / (high - low) * (width - thumb)

        def mouse(kind, x):
            self.call("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left",
                                                   "buttons": 0 if kind == "mouseReleased" else 1, "clickCount": 1})

        mouse("mousePressed", x_of(start))
        for k in range(1, steps + 1):
            mouse("mouseMoved", x_of(start + (value - start) * k / steps))
        mouse("mouseReleased", x_of(value))
        return float(self.evaluate(f"+document.querySelector({json.dumps(selector)}).value"))

    def screenshot(self, path: Path, selector: str | None = None) -> Path:
        """A PNG of the element ``selector`` (whole, scrolled into view), else of the viewport."""
        params = {"format": "png"}
        if selector is not None:
            box = self.evaluate(f"(() => {{ const e = document.querySelector({json.dumps(selector)}); "
                                "e.scrollIntoView(); const r = e.getBoundingClientRect(); "
                                "return [r.left + scrollX, r.top + scrollY, r.width, r.height]; })()")
            params.update(clip=dict(zip(("x", "y", "width", "height"), box), scale=1), captureBeyondViewport=True)
        data = self.call("Page.captureScreenshot", params)["data"]
        path.write_bytes(base64.b64decode(data))
        return path

    def problems(self) -> list[str]:
        """Console messages and uncaught exceptions the page reported so far."""
        found = []
        for event in self.events:
            if event.get("method") == "Runtime.exceptionThrown":
                found.append(event["params"]["exceptionDetails"].get("text", "exception"))
            elif event.get("method") == "Runtime.consoleAPICalled":
                found.append(" ".join(str(a.get("value", a.get("description"))) for a in event["params"]["args"]))
        return found

    def close(self) -> None:
        try:
            self._call("Browser.close", timeout=10)
        except BrowserError:
            pass
        os.close(self._commands)
        os.close(self._answers)
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
