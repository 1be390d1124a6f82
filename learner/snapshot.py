"""Model snapshots: safetensors weights plus JSON metadata, never pickle.

The metadata (under the safetensors header key ``robocal``) holds the schema version, robot,
its description (TOML text, for the kinematic input encoding), feature names, model/train
configs, seed and training metrics; the tensors hold the network weights, the fixed scalers and
the sensor transform ``T_6_S`` (float64, so predictions after a reload are bit-identical).
The physics base travels too (kind, note, description TOML and effects in the JSON; its frame
``T_0_B`` and tool as float64 tensors), so a reloaded model predicts what it predicted; so do
the joint angles and temperatures it was trained on (``joint_envelope``,
``temperature_envelope``, :mod:`learner.envelope`; absent in snapshots written before they
existed, which compensation then does not check), and why its intervals are not verified yet
(``unverified``, a carry's moved frames or missed intervals; absent: verified) and how much
wider its intervals must be on a later day (``drift_scale``; absent: not measured). Version
1 snapshots (before input encodings and members existed) load as ``encoding = "minmax"``, one
member; snapshots without a base load on the nominal.

>>> from kinematics.description import load_description
>>> from learner.config import ModelConfig, TrainConfig
>>> from learner.features import feature_spec
>>> spec = feature_spec(load_description("ur10"), 0, False)
>>> m = ErrorModel.create(spec, ModelConfig(hidden_layers=1, neurons=8), TrainConfig(), seed=0)
>>> snapshot_from_bytes(snapshot_to_bytes(m)).feature_names == m.feature_names
True
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from kinematics.dataset import atomic_write, temperature_columns
from kinematics.description import description_from_dict, description_to_toml
from kinematics.errors import RobocalError, SnapshotError
from kinematics.gap.model_file import EffectEntry
from learner.base import PhysicsBase
from learner.config import ModelConfig, TrainConfig
from learner.envelope import N_BINS, Envelope
from learner.features import FeatureSpec
from learner.model import ErrorModel

SCHEMA = "robocal.model"
SCHEMA_VERSION = 2
_READABLE_VERSIONS = (1, 2)
#: What version 1 snapshots, written before these fields existed, were.
_V1_MODEL = {"encoding": "minmax", "members": 1}
#: What a snapshot written before ``nll_variance_power`` was trained with: the plain NLL.
_TRAIN_BEFORE_POWER = {"nll_variance_power": 0.0}
_META_KEY = "robocal"
_SCALERS = ("feature_low", "feature_high", "label_mean", "label_std", "interval_scale")


def snapshot_to_bytes(model: ErrorModel, extra_meta: dict | None = None) -> bytes:
    """The model as safetensors bytes with JSON metadata (``extra_meta`` stored alongside)."""
    if not model.is_fitted:
        mean, std = np.zeros(6), np.ones(6)
    else:
        mean, std = model.label_mean, model.label_std
    tensors = {f"net.{k}": v.detach().contiguous() for k, v in model.net.state_dict().items()}
    scalers = (model.spec.low, model.spec.high, mean, std, model.interval_scale)
    for key, value in zip(_SCALERS, scalers, strict=True):
        tensors[key] = torch.as_tensor(np.asarray(value, dtype=np.float64))
    tensors["drift_scale"] = torch.as_tensor(np.asarray(model.drift_scale, dtype=np.float64))
    desc = model.spec.description
    if desc is not None:
        tensors["sensor_tool"] = torch.as_tensor(desc.tool)
    if model.envelope is not None:
        tensors |= _envelope_tensors(model.envelope, model.spec)
    base = model.base
    if base is not None:
        tensors["base_T_0_B"] = torch.as_tensor(np.array(base.T_0_B, dtype=np.float64))
        tensors["base_tool"] = torch.as_tensor(np.array(base.description.tool))  # never shared
        if base.frame_sigma is not None:
            tensors["base_frame_sigma"] = torch.as_tensor(np.asarray(base.frame_sigma, np.float64))
    meta = {
        "schema": SCHEMA,
        "version": SCHEMA_VERSION,
        "robot": model.robot,
        "description": None if desc is None else description_to_toml(desc),
        "feature_names": list(model.feature_names),
        "model_config": asdict(model.model_cfg),
        "train_config": asdict(model.train_cfg),
        "seed": model.seed,
        "fitted": model.is_fitted,
        "metrics": model.metrics,
        "base": None if base is None else base_meta(base),
        "residual_gain": model.residual_gain,
        "unverified": model.unverified,
        "extra": extra_meta or {},
    }
    try:
        text = json.dumps(meta, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise SnapshotError(f"snapshot metadata is not JSON-serialisable: {exc}") from None
    return st_save(tensors, metadata={_META_KEY: text})


def read_metadata(data: bytes, key: str = _META_KEY) -> dict:
    """The JSON object under ``key`` in a safetensors blob's ``__metadata__``, read from the
    header alone (``u64 LE length | header JSON | tensors``); the one header reader of robocal.

    A malformed header raises ValueError, KeyError or TypeError (callers name the file)."""
    header_len = int.from_bytes(data[:8], "little")
    return json.loads(json.loads(data[8 : 8 + header_len])["__metadata__"][key])


def snapshot_meta(data: bytes) -> dict:
    """The JSON metadata of a snapshot without building the model."""
    try:
        meta = read_metadata(data)
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise SnapshotError(f"not a robocal snapshot (bad safetensors header: {exc})") from None
    if meta.get("schema") != SCHEMA:
        raise SnapshotError(f"snapshot schema must be {SCHEMA!r}, got {meta.get('schema')!r}")
    if meta.get("version") not in _READABLE_VERSIONS:
        raise SnapshotError(
            f"snapshot version must be one of {_READABLE_VERSIONS}, got {meta.get('version')!r}"
        )
    return meta


def snapshot_from_bytes(data: bytes) -> ErrorModel:
    """Rebuild an :class:`ErrorModel` from :func:`snapshot_to_bytes` output."""
    meta = snapshot_meta(data)
    try:
        tensors = st_load(data)
    except (SafetensorError, ValueError) as exc:
        raise SnapshotError(f"snapshot tensors unreadable: {exc}") from None
    missing = [k for k in _SCALERS if k not in tensors]
    if missing:
        raise SnapshotError(f"snapshot lacks tensor(s) {', '.join(missing)}")
    try:
        desc = None
        if meta.get("description"):
            desc = description_from_dict(tomllib.loads(meta["description"]))
            desc = desc.with_tool(tensors["sensor_tool"].numpy())
        spec = FeatureSpec(
            names=tuple(meta["feature_names"]),
            low=tensors["feature_low"].numpy(),
            high=tensors["feature_high"].numpy(),
            description=desc,
        )
        model = ErrorModel(
            spec=spec,
            model_cfg=ModelConfig(**(_V1_MODEL | meta["model_config"])),
            train_cfg=TrainConfig(**(_TRAIN_BEFORE_POWER | meta["train_config"])),
            seed=int(meta["seed"]),
            robot=str(meta["robot"]),
            label_mean=tensors["label_mean"].numpy() if meta["fitted"] else None,
            label_std=tensors["label_std"].numpy() if meta["fitted"] else None,
            interval_scale=tensors["interval_scale"].numpy(),
            base=base_from_meta(meta.get("base"), tensors),
            residual_gain=float(meta.get("residual_gain", 1.0)),
            envelope=_envelope(tensors, spec),
            unverified=_unverified(meta.get("unverified")),
            drift_scale=_drift_scale(tensors),
        )
        state = {k[len("net.") :]: v for k, v in tensors.items() if k.startswith("net.")}
        model.net.load_state_dict(state, strict=True)
    except (KeyError, TypeError, RuntimeError, tomllib.TOMLDecodeError, RobocalError) as exc:
        raise SnapshotError(
            f"snapshot does not match its metadata: {exc}".splitlines()[0]
        ) from None
    model.metrics = dict(meta.get("metrics", {}))
    model.net.eval()
    return model


def copy_model(model: ErrorModel) -> ErrorModel:
    """An independent copy of ``model`` (through its snapshot: weights, scalers, base)."""
    return snapshot_from_bytes(snapshot_to_bytes(model))


def _drift_scale(tensors: dict) -> np.ndarray | None:
    """The ``drift_scale`` tensor: absent is not measured (None); one positive factor per label
    component, or a SnapshotError."""
    if "drift_scale" not in tensors:
        return None
    scale = tensors["drift_scale"].numpy()
    if scale.shape != (6,) or not np.all(np.isfinite(scale) & (scale > 0)):
        raise SnapshotError(f"snapshot drift_scale must be 6 positive factors, got {scale}")
    return scale


def _unverified(value: object) -> str:
    """The ``unverified`` reason of the metadata: absent or null is verified (""); anything but
    a string is a SnapshotError, not a reason."""
    if value is None or isinstance(value, str):
        return value or ""
    raise SnapshotError(f"snapshot unverified must be a string, got {type(value).__name__}")


def _envelope_tensors(envelope: Envelope, spec: FeatureSpec) -> dict[str, torch.Tensor]:
    """``joint_envelope`` (uint8 ``(n_joints, 72)``) and ``temperature_envelope`` (float64
    ``(n_thermometers, 2)``, lowest and highest °C, in the spec's order; absent without
    thermometers or when they were not recorded)."""
    tensors = {"joint_envelope": torch.as_tensor(np.asarray(envelope.joints, dtype=np.uint8))}
    names = temperature_columns(spec.names)
    known = envelope.temperatures
    if names and known is not None and all(n in known for n in names):
        ranges = [known[n] for n in names]
        tensors["temperature_envelope"] = torch.as_tensor(np.array(ranges, dtype=np.float64))
    return tensors


def _envelope(tensors: dict, spec: FeatureSpec) -> Envelope | None:
    """The envelope of the ``joint_envelope`` and ``temperature_envelope`` tensors; None when
    the first is absent, temperatures not recorded when the second is (snapshots written before
    they existed). Another shape is a SnapshotError: compensation indexes them."""
    if "joint_envelope" not in tensors:
        return None
    joints = tensors["joint_envelope"].numpy()
    shape = (spec.n_joints, N_BINS)
    if joints.shape != shape:
        raise SnapshotError(f"joint_envelope has shape {joints.shape}, expected {shape}")
    names = temperature_columns(spec.names)
    if "temperature_envelope" not in tensors:
        return Envelope(joints.astype(bool), None if names else {})
    ranges = tensors["temperature_envelope"].numpy()
    if ranges.shape != (len(names), 2):
        raise SnapshotError(
            f"temperature_envelope has shape {ranges.shape}, expected {(len(names), 2)}"
        )
    return Envelope(
        joints.astype(bool),
        {n: (float(lo), float(hi)) for n, (lo, hi) in zip(names, ranges, strict=True)},
    )


def base_meta(base: PhysicsBase) -> dict:
    """The physics base's JSON part (its frame and tool travel as float64 tensors)."""
    return {
        "kind": base.kind,
        "note": base.note,
        "condition": None if np.isnan(base.condition) else base.condition,
        "on_nominal": base.on_nominal,
        "description": description_to_toml(base.description),
        "effects": [asdict(e) for e in base.effects],
        "left_out": list(base.left_out),
    }


def base_from_meta(meta: dict | None, tensors: dict) -> PhysicsBase | None:
    """The physics base a snapshot records (None before bases existed: the nominal); its
    ``base_T_0_B``, ``base_tool`` (and ``base_frame_sigma``) from ``tensors``, torch or numpy."""
    if not meta:
        return None
    desc = description_from_dict(tomllib.loads(meta["description"]))
    note = str(meta.get("note", ""))
    condition = meta.get("condition", _legacy_condition(note))
    return PhysicsBase(
        kind=str(meta["kind"]),
        description=desc.with_tool(np.asarray(tensors["base_tool"], dtype=float)),
        T_0_B=np.asarray(tensors["base_T_0_B"], dtype=float),
        effects=tuple(EffectEntry(**e) for e in meta.get("effects", [])),
        note=note,
        condition=float("nan") if condition is None else float(condition),
        on_nominal=bool(meta.get("on_nominal", note.startswith("nominal:"))),
        frame_sigma=_frame_sigma(tensors),
        left_out=tuple(map(str, meta.get("left_out", []))),
    )


def _frame_sigma(tensors: dict) -> np.ndarray | None:
    """The ``base_frame_sigma`` tensor ``(r, 2, 4, 4)``; None when absent (a base whose frames
    were not re-identified, or a snapshot written before it existed)."""
    if "base_frame_sigma" not in tensors:
        return None
    sigma = np.asarray(tensors["base_frame_sigma"], dtype=float)
    if sigma.ndim != 4 or sigma.shape[1:] != (2, 4, 4):
        raise SnapshotError(f"base_frame_sigma has shape {sigma.shape}, expected (r, 2, 4, 4)")
    return sigma


def _legacy_condition(note: str) -> float | None:
    """The condition number that snapshots written before ``condition`` existed give only in
    their base's note (``"... condition number 10.7"``); None when it names none."""
    _, found, number = note.rpartition("condition number ")
    try:
        return float(number.split()[0]) if found else None
    except (ValueError, IndexError):
        return None


def save_snapshot(model: ErrorModel, path: str | Path, extra_meta: dict | None = None) -> Path:
    """Write the snapshot to ``path`` atomically (temporary file, then rename)."""
    return atomic_write_bytes(path, snapshot_to_bytes(model, extra_meta))


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically with the user's umask (see
    :func:`kinematics.dataset.atomic_write`)."""
    return atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def load_snapshot(path: str | Path) -> ErrorModel:
    """Read a snapshot file; a missing or malformed file raises :class:`SnapshotError`."""
    path = Path(path)
    if not path.is_file():
        raise SnapshotError(f"{path}: no such model snapshot")
    try:
        return snapshot_from_bytes(path.read_bytes())
    except SnapshotError as exc:
        raise SnapshotError(f"{path}: {exc}") from None
