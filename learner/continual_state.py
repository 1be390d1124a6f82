"""A continual learner's state as bytes: memory, held-out set, a carried day's points and
quarantine history as safetensors tensors, counters, rng state and the two model snapshots
(hex) as JSON metadata. Nothing is pickled. :func:`learner_state` builds the dict from a
:class:`~learner.continual.ContinualLearner`, :func:`restore_learner` puts it back.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError
from safetensors.numpy import load as np_load
from safetensors.numpy import save as np_save

from kinematics.errors import SnapshotError
from learner.base import PhysicsBase
from learner.carry import CarriedDay
from learner.quarantine import state_from_dict as quarantine_from_dict
from learner.snapshot import (
    base_from_meta,
    base_meta,
    read_metadata,
    snapshot_from_bytes,
    snapshot_to_bytes,
)


def state_path(model_path: str | Path) -> Path:
    """The continual state (memory, both models, counters) written beside a model file."""
    stem = Path(model_path).with_suffix("")
    return stem.with_name(stem.name + ".state.safetensors")


STATE_SCHEMA = "robocal.continual"
_META = ("n_withheld", "quarantine_meta", "day_fitted", "day_note", "day_seen_before", "day_aside")


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
        **{k: state[k] for k in _META if k in state},
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
        "day_x",
        "day_y",
        "day_frames",
        "day_aside_T_0_B",
        "day_aside_tool",
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
            **{k: meta[k] for k in _META if k in meta},
            **{k: bytes.fromhex(meta[k]) for k in ("model", "trained") if k in meta},
        }
    except (SafetensorError, ValueError, KeyError, TypeError) as exc:
        raise SnapshotError(f"continual state unreadable: {exc}") from None


def learner_state(learner: Any) -> dict:
    """Everything a restart of ``learner`` (a :class:`~learner.continual.ContinualLearner`; not
    imported here, which would be a cycle) needs: memory, held-out set, a carried day's points,
    counters, rng state, the published and the trained model's snapshots."""
    day = learner.day
    return {
        "memory_x": learner._mem_x.copy(),
        "memory_y": learner._mem_y.copy(),
        "holdout_x": learner._cal_x.copy(),
        "holdout_y": learner._cal_y.copy(),
        "aci_log_scale": learner.aci_log_scale.copy(),
        "n_seen": learner.n_seen,
        "version": learner.version,
        "n_withheld": learner.n_withheld,
        **({} if learner.day_scale is None else {"day_scale": learner.day_scale.copy()}),
        **(
            {} if day is None else {"day_x": day.x, "day_y": day.y, "day_frames": day.source_frames}
        ),
        **(
            {}
            if day is None
            else {
                "day_fitted": day.fitted,
                "day_note": day.source_note,
                "day_seen_before": day.seen_before,
            }
        ),
        **({} if day is None or day.aside is None else aside_state(day.aside)),
        **learner.quarantine.to_dict(),
        "rng": learner.rng.bit_generator.state,
        "model": snapshot_to_bytes(learner.model),
        "trained": snapshot_to_bytes(learner.trained),
    }


def aside_state(aside: PhysicsBase) -> dict:
    """A carried day's base set aside (:attr:`CarriedDay.aside`) as state entries: its JSON
    part as a snapshot records it, its frame and tool as arrays."""
    return {
        "day_aside": base_meta(aside),
        "day_aside_T_0_B": np.asarray(aside.T_0_B, dtype=float),
        "day_aside_tool": np.asarray(aside.description.tool, dtype=float),
    }


def restore_learner(learner: Any, state: dict) -> None:
    """Put ``learner`` back where :func:`learner_state` found it (its models replaced by the
    stored ones); an incomplete state or one of other features raises :class:`SnapshotError`."""
    try:
        model = snapshot_from_bytes(state["model"])
        # States written before the average existed trained the model they published.
        trained = snapshot_from_bytes(state.get("trained", state["model"]))
        mem_x = np.asarray(state["memory_x"], dtype=float)
        mem_y = np.asarray(state["memory_y"], dtype=float)
        # States written before the calibration set existed restart with an empty one.
        cal_x = np.asarray(state.get("holdout_x", mem_x[:0]), dtype=float)
        cal_y = np.asarray(state.get("holdout_y", mem_y[:0]), dtype=float)
        aci = np.asarray(state.get("aci_log_scale", np.zeros(6)), dtype=float)
        n_seen, version = int(state["n_seen"]), int(state["version"])
        rng_state = state["rng"]
        quarantine, n_withheld = quarantine_from_dict(state), int(state.get("n_withheld", 0))
        day_scale = state.get("day_scale")
        day = None
        if "day_x" in state:
            frames, note = np.asarray(state["day_frames"], dtype=float), str(state["day_note"])
            xy = np.asarray(state["day_x"], dtype=float), np.asarray(state["day_y"], dtype=float)
            # States written before the day's own count existed count it from the first point.
            before = int(state.get("day_seen_before", 0))
            aside = None
            if "day_aside" in state:
                arrays = {f"base_{k}": state[f"day_aside_{k}"] for k in ("T_0_B", "tool")}
                aside = base_from_meta(state["day_aside"], arrays)
            fitted = int(state["day_fitted"])
            day = CarriedDay(frames, note, *xy, fitted, before, aside)
    except (KeyError, TypeError, ValueError) as exc:
        raise SnapshotError(f"continual state is incomplete: {exc}") from None
    if model.feature_names != learner.model.feature_names:
        raise SnapshotError(
            f"continual state features {model.feature_names} differ from the learner's "
            f"{learner.model.feature_names}"
        )
    learner.model, learner.trained = model, trained
    learner._mem_x, learner._mem_y = mem_x, mem_y
    learner._cal_x, learner._cal_y = cal_x, cal_y
    learner.aci_log_scale = aci
    learner.n_seen, learner.version = n_seen, version
    learner.quarantine, learner.n_withheld = quarantine, n_withheld
    learner.day_scale = None if day_scale is None else np.asarray(day_scale, dtype=float)
    learner.day = day
    learner.rng.bit_generator.state = rng_state
