"""Structured logs: one JSON object per line on stderr, and a per-key rate limit for noise.

>>> limiter = RateLimiter(per_s=1.0, burst=2)
>>> [limiter.allow("bad", now=0.0) for _ in range(3)]
[True, True, False]
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any, TextIO


class RateLimiter:
    """A token bucket per key: ``burst`` at once, then ``per_s`` per second."""

    def __init__(self, per_s: float = 1.0, burst: int = 5) -> None:
        self.per_s, self.burst = per_s, burst
        self._tokens: dict[str, tuple[float, float]] = {}

    def allow(self, key: str, now: float | None = None) -> bool:
        now = time.monotonic() if now is None else now
        tokens, last = self._tokens.get(key, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - last) * self.per_s)
        allowed = tokens >= 1.0
        self._tokens[key] = (tokens - 1.0 if allowed else tokens, now)
        return allowed


class JsonLogger:
    """Writes ``{"ts", "level", "event", ...fields}`` lines; ``limited`` ones are rate-limited."""

    def __init__(self, stream: TextIO | None = None, per_s: float = 1.0, burst: int = 5) -> None:
        self._stream = stream
        self._lock = threading.Lock()
        self._limiter = RateLimiter(per_s, burst)
        self.suppressed = 0

    def log(self, level: str, event: str, **fields: Any) -> None:
        line = json.dumps(
            {"ts": round(time.time(), 3), "level": level, "event": event, **fields},
            default=str,
            separators=(",", ":"),
        )
        with self._lock:
            out = self._stream or sys.stderr
            out.write(line + "\n")
            out.flush()

    def info(self, event: str, **fields: Any) -> None:
        self.log("info", event, **fields)

    def limited(self, event: str, key: str, **fields: Any) -> None:
        """A warning logged at most at the configured rate per ``key`` (e.g. a drop reason)."""
        with self._lock:
            allowed = self._limiter.allow(key)
            if not allowed:
                self.suppressed += 1
        if allowed:
            self.log("warning", event, **fields)
