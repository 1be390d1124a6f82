"""What a browser shows of a served dashboard: headless Chromium on the viewer URL.

Rerun's web viewer draws everything into one WebGL canvas, so the page has no DOM to query.
What proves that the viewer connected and received the recording is on the screen: pixels of
the robot's link colour (the 3-D view draws the robot only from received data) and of the
per-point error series (a time series is drawn only from received scalars), plus the viewer's
requests to the recording's gRPC address. An empty viewer shows neither colour.

Driven by playwright with the system's Chromium (Debian's ``chromium``; playwright's own
browser downloads are never used). The software rasterizer (SwiftShader) stands in for a GPU.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stream.dashboard_layout import ERROR_RGB
from stream.dashboard_robot import LINK_RGB

TOP_BAR_PX = 40
CHROMIUM_ARGS = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist")


def find_chromium() -> str | None:
    """The system Chromium's path, or None when it is not installed."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def pixels(png: bytes) -> np.ndarray:
    """The RGB pixels ``(H, W, 3)`` of a PNG screenshot."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)


def colour_pixels(img: np.ndarray, rgb: tuple[int, int, int], tolerance: int = 12) -> int:
    """How many pixels lie within ``tolerance`` of ``rgb`` in every channel."""
    return int((np.abs(img - np.asarray(rgb)).max(axis=2) <= tolerance).sum())


@dataclass
class ViewerCheck:
    """What the page showed: robot-coloured and error-series-coloured pixels and the number of
    distinct colours (a drawn viewer has many, a blank page one) of the last screenshot, the
    requests it made to the gRPC address, the seconds until both colours were
    on screen (None: never), and the console errors."""

    robot_pixels: int = 0
    series_pixels: int = 0
    colours: int = 0
    grpc_requests: int = 0
    seconds_to_data: float | None = None
    console_errors: list[str] = field(default_factory=list)
    screenshot: bytes = b""


def shows_data(check: ViewerCheck, min_pixels: int = 200) -> bool:
    """Both the robot and the error series are on screen (``min_pixels`` each)."""
    return min(check.robot_pixels, check.series_pixels) >= min_pixels


def open_viewer(
    url: str,
    grpc_address: str,
    chromium: str,
    timeout_s: float = 90.0,
    until: Callable[[ViewerCheck], bool] = shows_data,
    viewport: tuple[int, int] = (1600, 1000),
    settle_s: float = 0.0,
    poll_s: float = 1.0,
) -> ViewerCheck:
    """Open ``url`` headless and screenshot it every ``poll_s`` until ``until(check)`` (by default:
    the recording's data is on screen; then ``seconds_to_data`` is set) or ``timeout_s``
    passes; ``settle_s`` more seconds before the last screenshot (a finished picture).
    Colours are counted below the viewer's top bar (its warning label is orange)."""
    from playwright.sync_api import sync_playwright

    check = ViewerCheck()
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, headless=True, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})

            def on_request(request) -> None:
                if grpc_address in request.url:
                    check.grpc_requests += 1

            page.on("request", on_request)
            page.on(
                "console",
                lambda m: check.console_errors.append(m.text[:300]) if m.type == "error" else None,
            )
            start = time.monotonic()
            page.goto(url)
            while time.monotonic() - start < timeout_s:
                page.wait_for_timeout(poll_s * 1000)
                check.screenshot = page.screenshot()
                img = pixels(check.screenshot)[TOP_BAR_PX:]
                check.robot_pixels = colour_pixels(img, LINK_RGB, tolerance=40)
                check.series_pixels = colour_pixels(img, ERROR_RGB)
                check.colours = len(np.unique(img.reshape(-1, 3), axis=0))
                if shows_data(check) and check.seconds_to_data is None:
                    check.seconds_to_data = time.monotonic() - start
                if until(check):
                    break
            if settle_s > 0:
                page.wait_for_timeout(settle_s * 1000)
                check.screenshot = page.screenshot()
        finally:
            browser.close()
    return check


def serve_rrd(rrd: str | Path, web_port: int, grpc_port: int) -> subprocess.Popen:
    """``rerun --serve-web`` of an .rrd file, this interpreter's rerun, in a process group of its
    own (``python -m rerun`` starts the viewer binary as a child): stop it with :func:`stop`."""
    args = ["--serve-web", "--web-viewer-port", str(web_port), "--port", str(grpc_port)]
    return subprocess.Popen(
        [sys.executable, "-m", "rerun", *args, str(rrd)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def stop(server: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """End a :func:`serve_rrd` server and its children: SIGTERM to the group, then SIGKILL to
    whatever of it is left after ``timeout_s``."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(server.pid, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        server.wait(timeout_s)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(server.pid, signal.SIGKILL)
    server.wait()
