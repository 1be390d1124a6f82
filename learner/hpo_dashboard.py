"""optuna-dashboard on a study, served from a background thread of the search's process.

optuna-dashboard is an optional extra (``pip install -e '.[dashboard]'``); without it the
request fails in one line before any work starts.
"""

from __future__ import annotations

import threading
from pathlib import Path

from kinematics.errors import ConfigError
from learner.hpo_study import open_storage


def start_dashboard(storage: str | Path, *, host: str = "127.0.0.1", port: int = 8080) -> str:
    """Serve optuna-dashboard on ``storage`` (journal file or RDB URL) from a daemon thread;
    its URL. ConfigError when optuna-dashboard is not installed or the port is not valid."""
    try:
        from optuna_dashboard import run_server
    except ImportError:
        raise ConfigError(
            "--dashboard needs optuna-dashboard: pip install -e '.[dashboard]' "
            "(or pip install optuna-dashboard)"
        ) from None
    if not 0 < port < 65536:
        raise ConfigError(f"dashboard port must be in 1..65535, got {port}")
    thread = threading.Thread(
        target=run_server,
        args=(open_storage(storage),),
        kwargs={"host": host, "port": port},
        name="optuna-dashboard",
        daemon=True,
    )
    thread.start()
    return f"http://{host}:{port}/"
