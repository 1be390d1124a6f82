"""Screenshot of the full dashboard for the README, and how long the browser took to show it.

    .venv/bin/python bench/dashboard_screenshot.py out/robocal.rrd --out docs/dashboard.png

Serves the recording with ``rerun --serve-web``, opens the viewer URL in headless Chromium
(Debian's ``chromium``, software rendering), waits until the robot and the per-point error
series are on screen and the picture has stopped changing (the whole file is in), and writes
a palette PNG (small enough for git). Prints the seconds until the first data and the whole
recording were on screen.
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from collections.abc import Callable
from pathlib import Path

from stream.bus import free_port
from stream.dashboard import viewer_url
from stream.dashboard_view import (
    TOP_BAR_PX,
    ViewerCheck,
    find_chromium,
    open_viewer,
    pixels,
    serve_rrd,
    stop,
)


def still_for(shots: int) -> Callable[[ViewerCheck], bool]:
    """True once the data is on screen and the picture (below the top bar, whose latency label
    ticks) has not changed for ``shots`` screenshots in a row: the whole file is in."""
    last: list[int] = []

    def until(check: ViewerCheck) -> bool:
        if check.seconds_to_data is None:
            return False
        last.append(hash(pixels(check.screenshot)[TOP_BAR_PX:].tobytes()))
        return len(last) > shots and len(set(last[-shots - 1 :])) == 1

    return until


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rrd", help="recording, e.g. out/robocal.rrd from make demo")
    parser.add_argument("--out", default="docs/dashboard.png")
    parser.add_argument("--width", type=int, default=1600)
    parser.add_argument("--height", type=int, default=1000)
    parser.add_argument("--colours", type=int, default=96, help="PNG palette size")
    parser.add_argument("--poll", type=float, default=3.0, help="s between screenshots")
    parser.add_argument("--still", type=int, default=4, help="unchanged screenshots in a row")
    parser.add_argument("--timeout", type=float, default=600.0, help="s to wait at most")
    args = parser.parse_args()
    chromium = find_chromium()
    if chromium is None:
        print("needs Debian's chromium (apt-get install chromium)", file=sys.stderr)
        return 2
    web, grpc = free_port(), free_port()
    server = serve_rrd(args.rrd, web, grpc)
    try:
        time.sleep(3.0)  # the server reads the file before it answers
        start = time.monotonic()
        check = open_viewer(
            viewer_url("127.0.0.1", web, grpc),
            f":{grpc}/",
            chromium,
            timeout_s=args.timeout,
            until=still_for(args.still),
            poll_s=args.poll,
            viewport=(args.width, args.height),
        )
    finally:
        stop(server)
    if check.seconds_to_data is None:
        print(f"the recording never showed ({check.console_errors[:3]})", file=sys.stderr)
        return 1
    from PIL import Image

    img = Image.open(io.BytesIO(check.screenshot)).convert("RGB")
    img = img.quantize(colors=args.colours, method=Image.Quantize.MEDIANCUT)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    img.save(args.out, optimize=True)
    size_kib = Path(args.out).stat().st_size / 1024
    whole_s = time.monotonic() - start - args.still * args.poll
    print(
        f"first data on screen after {check.seconds_to_data:.1f} s, the whole recording after "
        f"{whole_s:.1f} s; wrote {args.out} ({size_kib:.0f} KiB)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
