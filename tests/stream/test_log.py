"""Structured logs: JSON lines, and a flood of bad-message warnings stays bounded."""

import io
import json

from stream.log import JsonLogger, RateLimiter


def test_json_lines_and_bounded_warnings():
    out = io.StringIO()
    log = JsonLogger(stream=out, per_s=1.0, burst=3)
    log.info("started", cell="c1")
    for i in range(1000):
        log.limited("message_dropped", key="window:malformed", seq=i)
    log.limited("message_dropped", key="window:late", seq=0)
    lines = [json.loads(x) for x in out.getvalue().splitlines()]
    assert lines[0] == {"ts": lines[0]["ts"], "level": "info", "event": "started", "cell": "c1"}
    reasons = [x["seq"] for x in lines[1:]]
    assert reasons[:3] == [0, 1, 2] and len(lines) <= 1 + 3 + 1 + 1
    assert log.suppressed >= 995


def test_rate_limiter_refills():
    r = RateLimiter(per_s=2.0, burst=1)
    assert [r.allow("k", now=t) for t in (0.0, 0.1, 0.6, 0.7)] == [True, False, True, False]
