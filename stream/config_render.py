"""A ``robocal run`` config written from Python: the TOML file that benches, tests and tools
hand to a daemon subprocess, built as the dict :func:`stream.config.config_from_dict` reads.

>>> raw = loopback_config("c1", 7447, {"name": "ur10", "description": "ur10"})
>>> raw["bus"]
{'mode': 'peer', 'listen': ['tcp/127.0.0.1:7447'], 'multicast_scouting': False}
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import tomli_w

from stream.bus import BusConfig
from stream.config import config_from_dict


def loopback_config(cell: str, port: int, *robots: dict[str, Any], **tables: Any) -> dict:
    """The TOML layout of a config for ``cell`` whose daemon is a peer listening on
    ``tcp/127.0.0.1:<port>`` with multicast scouting off (:meth:`BusConfig.loopback`), with
    ``robots`` as ``[[robot]]`` and ``tables`` as further keys and tables, e.g.
    ``learner={"model": {"neurons": 16}}``."""
    bus = BusConfig.loopback(port, listen=True)
    return {
        "cell": cell,
        **tables,
        "bus": {
            "mode": bus.mode,
            "listen": list(bus.listen),
            "multicast_scouting": bus.multicast_scouting,
        },
        "robot": list(robots),
    }


def write_config(path: str | Path, raw: dict[str, Any]) -> Path:
    """Check ``raw`` as the daemon will (ConfigError, and nothing written, when it would refuse
    it) and write it to ``path`` as TOML; returns ``path``."""
    config_from_dict(raw)
    path = Path(path)
    path.write_text(tomli_w.dumps(raw))
    return path
