"""The simulated measurement cell: a true robot measured by a laser tracker, as a dataset.

:class:`SimulatedCell` ties a scenario's program, temperatures, loads and true robot together
for one campaign seed. It measures each visit as a real cell would: the probe pose in the
tracker frame (with tracker noise and robot repeatability), the secondary encoders (which see
the elastic deflection), the temperatures. :func:`simulate` turns a campaign into the dataset
format of DESIGN.md, with ground-truth ``true_*`` columns and the scenario in the metadata.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from kinematics.accuracy import AccuracySummary, accuracy_summary
from kinematics.dataset import Dataset, DatasetMeta, temperature_column, write_dataset
from kinematics.description import load_description
from kinematics.effects import Conditions, Perturbation, ctrl_to_dh_delta
from kinematics.errors import ConfigError
from kinematics.model import RobotModel
from kinematics.transforms import pose_error, skew_to_rotation, xyz_quat_from_transform
from sim_sources.iso_cube import make_cube_program
from sim_sources.program import Program, make_program
from sim_sources.scenarios import Scenario
from sim_sources.thermal import ThermalHistory
from sim_sources.truth import TrueRobot

CHUNK = 256


@dataclass(frozen=True)
class Measurement:
    """What the cell records at some visits, plus what only the simulator knows (SI units).

    ``T_W_S`` measured probe poses in the tracker frame (N, 4, 4); ``qs`` secondary encoders
    (N, n) rad; ``T_0_S_true`` the noise-free true poses in the base frame; ``contributions``
    per effect the pose error (N, 6) it causes; ``noise_m`` (N,) the position noise norm.
    """

    T_W_S: np.ndarray
    qs: np.ndarray
    T_0_S_true: np.ndarray
    contributions: dict[str, np.ndarray]
    noise_m: np.ndarray


def air_spring_force(model: RobotModel, q: np.ndarray, magnitude_n: np.ndarray) -> np.ndarray:
    """Base-frame forces (N, 3) N of an air spring pushing the probe back along its z axis."""
    z_axis = model.fk(q)[:, :3, 2]
    return -np.asarray(magnitude_n, dtype=float)[:, None] * z_axis


class SimulatedCell:
    """One seeded campaign of a scenario: program, temperatures, loads, true robot, noise.

    >>> from sim_sources.scenarios import get_scenario
    >>> cell = SimulatedCell(get_scenario("nominal"), n=3, seed=0)
    >>> len(cell.program), cell.measure().T_W_S.shape
    (3, (3, 4, 4))
    """

    def __init__(self, scenario: Scenario, n: int, seed: int) -> None:
        self.scenario = scenario
        self.seed = int(seed)
        self.model = RobotModel(load_description(scenario.robot))
        self.truth = TrueRobot(self.model, scenario.build_effects(self.model.description))
        rng = np.random.default_rng(self.seed)
        if scenario.program.kind == "iso9283":
            self.program: Program = make_cube_program(
                self.model, n, scenario.program, scenario.cell
            )
        else:
            self.program = make_program(self.model, n, rng, scenario.program, scenario.cell)
        self.thermal = ThermalHistory.compute(
            scenario.thermal, *self.program.heating_schedule(), self.program.duration_s
        )
        self.T_W_0 = scenario.cell.T_W_0()
        noise = scenario.noise_levels if scenario.noise else None
        n_joints = self.model.description.n_joints
        self._joint_noise = _gauss(rng, (n, n_joints), noise and noise.repeatability_sigma_rad)
        self._tracker_p = _gauss(rng, (n, 3), noise and noise.tracker_position_rms_m / np.sqrt(3))
        self._tracker_r = _gauss(rng, (n, 3), noise and noise.tracker_rotation_rms_rad / np.sqrt(3))
        self.tool_force_n = air_spring_force(self.model, self.program.q, self.program.air_spring_n)

    @property
    def temperature_names(self) -> tuple[str, ...]:
        return self.thermal.sensors

    def conditions(self, index: np.ndarray | None = None) -> Conditions:
        """Effect conditions at the measured visits ``index`` (all when None)."""
        index = np.arange(len(self.program)) if index is None else np.asarray(index)
        p = self.program
        t = p.t_measure_s[index]
        return Conditions(
            q=p.q[index],
            t=t,
            temperatures=self.thermal.at(t),
            temperature_names=self.temperature_names,
            approach=p.approach[index],
            payload_kg=p.payload_kg[index],
            tool_force_n=self.tool_force_n[index],
        )

    def measure(self, index: np.ndarray | None = None) -> Measurement:
        """Measure visits ``index`` (all when None); the noise of a visit is fixed by the seed."""
        index = np.arange(len(self.program)) if index is None else np.asarray(index)
        cond = self.conditions(index)
        perts = self.truth.perturbations(cond)
        T_true = self.truth.poses(cond, perts)
        contributions = self.truth.contributions(cond, perts)
        # Repeatability: the joints stop slightly off target; the effects see the actual angles.
        eps = self._joint_noise[index]
        moved = replace(cond, q=cond.q + eps)
        perts_noisy = dict(self.truth.perturbations(moved) if np.any(eps) else perts)
        perts_noisy["repeatability"] = _joint_offset(self.model, eps)
        # The tracker adds its own noise to the pose it reports in its frame {W}.
        T_W_S = self.T_W_0[None] @ self.truth.poses(cond, perts_noisy)
        T_W_S[:, :3, 3] += self._tracker_p[index]
        T_W_S[:, :3, :3] = skew_to_rotation(self._tracker_r[index]) @ T_W_S[:, :3, :3]
        p_true = (self.T_W_0[None] @ T_true)[:, :3, 3]
        return Measurement(
            T_W_S=T_W_S,
            qs=cond.q + eps + self.truth.deflection(moved),
            T_0_S_true=T_true,
            contributions=contributions,
            noise_m=np.linalg.norm(T_W_S[:, :3, 3] - p_true, axis=1),
        )


def _gauss(rng: np.random.Generator, shape: tuple[int, ...], sigma: float | None) -> np.ndarray:
    """Seeded normal noise, drawn even when ``sigma`` is off so streams stay aligned."""
    draw = rng.standard_normal(shape)
    return draw * sigma if sigma else np.zeros(shape)


def _joint_offset(model: RobotModel, eps_ctrl: np.ndarray) -> Perturbation:
    out = Perturbation.zero(*eps_ctrl.shape)
    out.dq = ctrl_to_dh_delta(model.description, eps_ctrl)
    return out


def simulate(
    scenario: Scenario, n: int, seed: int, progress: Callable[[int], None] | None = None
) -> Dataset:
    """The campaign of ``scenario`` with ``n`` points and ``seed`` as a dataset (tracker frame).

    ``progress(k)`` is called with the number of points just measured, for a progress bar.
    """
    if n < 1:
        raise ConfigError(f"a simulated campaign needs n >= 1 points, got {n}")
    cell = SimulatedCell(scenario, n, seed)
    parts = []
    for start in range(0, n, CHUNK):
        index = np.arange(start, min(start + CHUNK, n))
        parts.append(_rows(cell, index))
        if progress is not None:
            progress(len(index))
    table = pd.concat(parts, ignore_index=True)
    desc = cell.model.description
    params = dict(zip(cell.truth.names, (p for _, p in cell.truth.effects), strict=True))
    meta = DatasetMeta(
        robot=scenario.robot if scenario.model_file else desc.name,
        frame="tracker",
        T_W_0=cell.T_W_0.tolist(),
        T_6_S=desc.tool.tolist(),
        noise_floor_m=float(table.pop("_noise_m").mean()),
        extra={
            "source": "robocal simulated cell",
            "scenario": scenario.name,
            "scale": scenario.scale,
            "noise": scenario.noise,
            "seed": int(seed),
            "robot_seed": scenario.robot_seed,
            "effect_options": {e.name: e.options() for e, _ in cell.truth.effects if e.options()},
            "temperature_sensors": list(cell.temperature_names),
            **({"program": cell.program.info} if cell.program.info else {}),
            "effects": {
                e.name: dict(zip(e.parameter_names(desc), map(float, params[e.name]), strict=True))
                for e, _ in cell.truth.effects
            },
        },
    )
    return Dataset(table, meta)


def _rows(cell: SimulatedCell, index: np.ndarray) -> pd.DataFrame:
    """The dataset rows of visits ``index``."""
    m = cell.measure(index)
    cond = cell.conditions(index)
    n_joints = cond.q.shape[1]
    xyz, quat = xyz_quat_from_transform(m.T_W_S)
    true_error = pose_error(m.T_0_S_true, cell.model.fk(cond.q))
    cols: dict[str, np.ndarray] = {"t": cond.t}
    cols |= {f"q{i + 1}": cond.q[:, i] for i in range(n_joints)}
    cols |= {f"qs{i + 1}": m.qs[:, i] for i in range(n_joints)}
    cols |= {
        temperature_column(name): cond.temperatures[:, k]
        for k, name in enumerate(cond.temperature_names)
    }
    cols |= dict(zip(("x", "y", "z"), xyz.T, strict=True))
    cols |= dict(zip(("qx", "qy", "qz", "qw"), quat.T, strict=True))
    for k, comp in enumerate(("ex", "ey", "ez", "erx", "ery", "erz")):
        cols[f"true_{comp}"] = true_error[:, k]
    for name, err in m.contributions.items():
        cols |= {f"true_{name}_{c}": err[:, k] for k, c in enumerate(("dx", "dy", "dz"))}
    cols["true_payload_kg"] = np.asarray(cond.payload_kg, dtype=float)
    cols |= {f"true_f{c}_n": cond.tool_force_n[:, k] for k, c in enumerate("xyz")}
    cols |= {f"true_approach{i + 1}": cond.approach[:, i] for i in range(n_joints)}
    cols["_noise_m"] = m.noise_m
    return pd.DataFrame(cols)


@dataclass(frozen=True)
class CampaignReport:
    """What :func:`write_campaign` wrote: the file, the campaign and its uncalibrated accuracy
    (position error of measured vs nominal poses, mm; ``kinematics.accuracy``)."""

    path: Path
    scenario: str
    n: int
    seed: int
    duration_s: float
    noise_floor_m: float
    accuracy: AccuracySummary

    def to_dict(self) -> dict:
        return {
            "out": str(self.path),
            "scenario": self.scenario,
            "n": self.n,
            "seed": self.seed,
            "duration_s": self.duration_s,
            "noise_floor_m": self.noise_floor_m,
            **self.accuracy.to_dict(),
        }


def write_campaign(
    scenario: Scenario,
    n: int,
    seed: int,
    out: str | Path,
    progress: Callable[[int], None] | None = None,
) -> CampaignReport:
    """Simulate a campaign, write it (``.parquet`` or ``.csv`` + sidecar) and summarise it."""
    ds = simulate(scenario, n, seed, progress)
    path = write_dataset(ds, out)
    return CampaignReport(
        path=path,
        scenario=scenario.name,
        n=len(ds),
        seed=int(seed),
        duration_s=float(ds.table["t"].max()),
        noise_floor_m=float(ds.meta.noise_floor_m),
        accuracy=uncalibrated_accuracy(ds),
    )


def uncalibrated_accuracy(ds: Dataset) -> AccuracySummary:
    """Accuracy of a simulated dataset against the nominal model of its robot."""
    return accuracy_summary(ds, load_description(ds.meta.robot))
