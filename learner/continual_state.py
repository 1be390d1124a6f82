"""A continual learner's state as bytes: memory, held-out set and quarantine history as
safetensors tensors, counters, rng state and the two model snapshots (hex) as JSON metadata.
Nothing is pickled. :meth:`learner.continual.ContinualLearner.state_dict` builds the dict.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load as np_load
from safetensors.numpy import save as np_save

from kinematics.errors import SnapshotError
from learner.snapshot import read_metadata


def state_path(model_path: str | Path) -> Path:
    """The continual state (memory, both models, counters) written beside a model file."""
    stem = Path(model_path).with_suffix("")
    return stem.with_name(stem.name + ".state.safetensors")


STATE_SCHEMA = "robocal.continual"


def state_to_bytes(state: dict) -> bytes:
    """A :meth:`ContinualLearner.state_dict` as safetensors bytes (memory as tensors, the rest
    as JSON metadata, the model snapshot hex-encoded)."""
    meta = {
        "schema": STATE_SCHEMA,
        "n_seen": state["n_seen"],
        "version": state["version"],
        "rng": state["rng"],
        "model": state["model"].hex(),
        "trained": state["trained"].hex(),
        **{k: state[k] for k in ("n_withheld", "quarantine_meta") if k in state},
    }
    keys = (
        "memory_x",
        "memory_y",
        "holdout_x",
        "holdout_y",
        "aci_log_scale",
        "day_scale",
        "quarantine_labels",
        "quarantine_residuals",
    )
    arrays = {k: np.ascontiguousarray(state[k]) for k in keys if k in state}
    return np_save(arrays, metadata={"robocal": json.dumps(meta)})


def state_from_bytes(data: bytes) -> dict:
    """Inverse of :func:`state_to_bytes`; a malformed blob raises :class:`SnapshotError`."""
    try:
        arrays = np_load(data)
        meta = read_metadata(data)
        if meta.get("schema") != STATE_SCHEMA:
            raise SnapshotError(
                f"state schema must be {STATE_SCHEMA!r}, got {meta.get('schema')!r}"
            )
        return {
            **arrays,
            **{k: meta[k] for k in ("n_seen", "version", "rng")},
            **{k: meta[k] for k in ("n_withheld", "quarantine_meta") if k in meta},
            **{k: bytes.fromhex(meta[k]) for k in ("model", "trained") if k in meta},
        }
    except (SafetensorError, ValueError, KeyError, TypeError) as exc:
        raise SnapshotError(f"continual state unreadable: {exc}") from None
