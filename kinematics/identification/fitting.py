"""Nonlinear least squares over a list of effects, with finite-difference Jacobians.

The residual of point k is the pose error ``[p_m - p_c ; w vec(R_m R_c^T)]`` of the measured
pose against ``T_W_0 · perturbed_poses(...)``; ``w`` (m/rad) weighs orientation against
position. With ``rotation_weight_m=None`` it is chosen from the data: a first fit with
``w = 1``, then ``w = sigma_position / sigma_rotation`` of its residual components, refit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from kinematics.effects._base import Effect, Perturbation, dh_table, perturbed_poses
from kinematics.identification.conditions import Observations
from kinematics.model import RobotModel
from kinematics.transforms import invert, pose_error, vee_skew

#: Pose displacement (m) a finite-difference step aims at.
_FD_TARGET_M = 1e-5
_FD_PROBE = 1e-6

Block = tuple[Effect, np.ndarray]


def predicted_poses(model: RobotModel, obs: Observations, blocks: list[Block]) -> np.ndarray:
    """Predicted poses ``(N, 4, 4)`` in the dataset's frame for the effects ``blocks``."""
    return obs.T_W_0[None] @ perturbed_poses(model, obs.cond, blocks)


def residual_matrix(model: RobotModel, obs: Observations, blocks: list[Block]) -> np.ndarray:
    """Unweighted pose errors ``(N, 6)`` (m, rad) of the measurements against the model."""
    return pose_error(obs.T_measured, predicted_poses(model, obs, blocks))


def _weighted(E: np.ndarray, w: float) -> np.ndarray:
    return np.concatenate([E[:, :3], w * E[:, 3:]], axis=1).ravel()


def _split(x: np.ndarray, blocks: list[Block]) -> list[Block]:
    out, start = [], 0
    for effect, p in blocks:
        out.append((effect, x[start : start + len(p)]))
        start += len(p)
    return out


def _rot_z(th: np.ndarray) -> np.ndarray:
    R = np.zeros(th.shape + (3, 3))
    c, s = np.cos(th), np.sin(th)
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def _rot_axis(angle: np.ndarray, axis: int) -> np.ndarray:
    """Rotations about x (axis 0) or y (axis 1) by ``angle`` ``(N,)``."""
    R = np.zeros(angle.shape + (3, 3))
    c, s = np.cos(angle), np.sin(angle)
    i, j = [k for k in range(3) if k != axis]
    R[..., axis, axis] = 1.0
    R[..., i, i], R[..., j, j] = c, c
    R[..., i, j], R[..., j, i] = (-s, s) if axis == 0 else (s, -s)
    return R


def channel_jacobian(model: RobotModel, obs: Observations, total: Perturbation) -> np.ndarray:
    """``d[p; theta] / d channel`` ``(N, 6, 5n + 12)`` of the probe pose in the base frame.

    Channels: per joint the DH deltas (a, d, alpha, beta, offset; a joint-angle offset acts as
    the offset), then a left twist of the base correction and a right twist of the tool
    correction (translation, rotation). ``p`` moves, ``theta`` is a world-frame rotation.
    """
    desc = model.description
    n, N = desc.n_joints, obs.n_points
    dh = dh_table(desc)[None] + total.ddh
    theta = desc.to_dh(obs.cond.q) + total.dq + dh[:, :, 4]
    R, p = total.base[:, :3, :3].copy(), total.base[:, :3, 3].copy()
    axes, points = [], []
    for i in range(n):
        R1 = R @ _rot_z(theta[:, i])
        o2 = p + np.einsum(
            "nij,nj->ni", R1, np.stack([dh[:, i, 0], 0 * theta[:, i], dh[:, i, 1]], -1)
        )
        R2 = R1 @ _rot_axis(dh[:, i, 2], 0)
        # a: along x1; d: along z; alpha: about x1 at o2; beta: about y2 at o2; offset: z at p.
        axes += [R1[:, :, 0], R[:, :, 2], R1[:, :, 0], R2[:, :, 1], R[:, :, 2]]
        points += [None, None, o2, o2, p]
        R, p = R2 @ _rot_axis(dh[:, i, 3], 1), o2
    P = np.concatenate(
        [np.concatenate([R, p[..., None]], -1), np.tile([0, 0, 0, 1.0], (N, 1, 1))], 1
    )
    P = P @ desc.tool[None] @ total.tool
    p_end = P[:, :3, 3]
    J = np.zeros((N, 6, 5 * n + 12))
    for c, (axis, point) in enumerate(zip(axes, points, strict=True)):
        if point is None:
            J[:, :3, c] = axis
        else:
            J[:, :3, c] = np.cross(axis, p_end - point)
            J[:, 3:, c] = axis
    eye = np.eye(3)
    J[:, :3, 5 * n : 5 * n + 3] = eye
    J[:, :3, 5 * n + 3 : 5 * n + 6] = -_skew(p_end)
    J[:, 3:, 5 * n + 3 : 5 * n + 6] = eye
    J[:, :3, 5 * n + 6 : 5 * n + 9] = P[:, :3, :3]
    J[:, 3:, 5 * n + 9 :] = P[:, :3, :3]
    return J


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return S - np.swapaxes(S, -1, -2)


def _channel_delta(plus: Perturbation, minus: Perturbation) -> np.ndarray:
    """The channel change ``(N, 5n + 12)`` from perturbation ``minus`` to ``plus``."""
    ddh = plus.ddh - minus.ddh
    ddh[:, :, 4] += plus.dq - minus.dq
    out = np.zeros((len(ddh), ddh[0].size + 12))
    out[:, : ddh[0].size] = ddh.reshape(len(ddh), -1)
    if not np.array_equal(plus.base, minus.base):
        B = plus.base @ invert(minus.base)
        out[:, -12:-9], out[:, -9:-6] = B[:, :3, 3], vee_skew(B[:, :3, :3])
    if not np.array_equal(plus.tool, minus.tool):
        T = invert(minus.tool) @ plus.tool
        out[:, -6:-3], out[:, -3:] = T[:, :3, 3], vee_skew(T[:, :3, :3])
    return out


def _total(perts: list[Perturbation], n_points: int, n_joints: int) -> Perturbation:
    total = Perturbation.zero(n_points, n_joints)
    for p in perts:
        total = total.combine(p)
    return total


def _rotation_map(T_measured: np.ndarray, T_computed: np.ndarray) -> np.ndarray:
    """``M (N, 3, 3)`` with ``d vec(R_m R_c^T) = -M dtheta`` for a world rotation ``dtheta``
    of the computed pose."""
    E = np.einsum("nij,nkj->nik", T_measured[:, :3, :3], T_computed[:, :3, :3])
    return np.stack([vee_skew(E @ _skew(e)) for e in np.eye(3)], axis=-1)


def jacobian(
    model: RobotModel,
    obs: Observations,
    blocks: list[Block],
    w: float,
    only: int | None = None,
    steps: dict[tuple[int, int], float] | None = None,
) -> np.ndarray:
    """Jacobian ``(6N, p)`` of the weighted residual w.r.t. the parameters of ``blocks`` (all,
    or only those of block ``only``).

    The pose's derivative w.r.t. the perturbation channels is analytic
    (:func:`channel_jacobian`); each parameter's effect on the channels is a forward
    difference with a step that moves the pose by about 10 um (found by a probe once and kept
    in ``steps``, keyed by block and parameter index, across calls).
    """
    steps = {} if steps is None else steps
    N, n = obs.n_points, model.description.n_joints
    perts = [e.perturbation(model, np.asarray(p, float), obs.cond) for e, p in blocks]
    Jch = channel_jacobian(model, obs, _total(perts, N, n))
    dR = _rotation_map(obs.T_measured, predicted_poses(model, obs, blocks))
    Rw = obs.T_W_0[:3, :3]
    cols = []
    for b, ((effect, p), pert) in enumerate(zip(blocks, perts, strict=True)):
        if only is not None and b != only:
            continue
        p = np.asarray(p, float)
        for j in range(len(p)):
            if (b, j) not in steps:
                moved = np.abs(_moved(Jch, effect, model, p, j, _FD_PROBE, pert, obs)).max()
                steps[b, j] = _FD_PROBE * _FD_TARGET_M / moved if moved > 0 else _FD_PROBE
            d = _moved(Jch, effect, model, p, j, steps[b, j], pert, obs) / steps[b, j]
            de_p = -d[:, :3] @ Rw.T
            de_r = -np.einsum("nij,nj->ni", dR, d[:, 3:] @ Rw.T)
            cols.append(np.concatenate([de_p, w * de_r], axis=1).ravel())
    return np.stack(cols, axis=1) if cols else np.zeros((6 * N, 0))


def tool_motion_rms(J: np.ndarray) -> np.ndarray:
    """Per column of a :func:`jacobian` taken with rotation weight 1 (``(6N, p)``), how far a unit
    change of that parameter moves the tool pose, RMS over the ``N`` points (m per unit;
    rotations count on a 1 m lever): the scale a prior on the parameter is stated in."""
    return np.sqrt(np.mean(np.sum(J.reshape(-1, 6, J.shape[1]) ** 2, axis=1), axis=0))


def _moved(Jch, effect, model, p, j, h, pert, obs) -> np.ndarray:
    """The pose change ``(N, 6)`` (base frame) when parameter ``j`` of ``effect`` grows by h."""
    dx = np.zeros(len(p))
    dx[j] = h
    plus = effect.perturbation(model, p + dx, obs.cond)
    return np.einsum("nkc,nc->nk", Jch, _channel_delta(plus, pert))


@dataclass(frozen=True, kw_only=True)
class FitResult:
    """Fitted parameters per block with standard uncertainties (and ``cov``, the prior's rows
    included), the residual and ``jac``, the Jacobian of its weighted rows (without them)."""

    params: list[np.ndarray]
    std: list[np.ndarray]
    cov: np.ndarray
    jac: np.ndarray
    residual: np.ndarray
    rss: float
    dof: int
    rotation_weight_m: float

    def blocks(self, effects: list[Effect]) -> list[Block]:
        return list(zip(effects, self.params, strict=True))


def fit_effects(
    model: RobotModel,
    obs: Observations,
    blocks: list[Block],
    rotation_weight_m: float | None = None,
    max_nfev: int = 50,
    prior_std: np.ndarray | None = None,
) -> FitResult:
    """Fit all parameters of ``blocks`` (start values given) by ``least_squares``.

    Uncertainties are ``sqrt(diag(s^2 (J^T J)^+))`` with ``s^2 = RSS / (6N - p)``. With
    ``prior_std`` (one per parameter, in its unit) the fit is a MAP estimate under a Gaussian
    prior centred on zero (every parameter is a deviation from the model, zero is none,
    whatever the start values): one residual row ``s_p x / prior_std`` per
    parameter, ``s_p`` the RMS position residual per component of a first, free fit (what
    these parameters cannot explain: the points' noise), so a parameter the points hardly
    excite stays near zero. An infinite ``prior_std`` leaves its parameter free.
    (A Cauchy prior, which lets a clearly shown move go, released the tilt that one region's
    local error fakes: UR10 B -> A frames from 10 points 1.03 mm against 0.77 mm Gaussian.)
    """
    blocks = [(e, np.asarray(p, dtype=float)) for e, p in blocks]
    w = 1.0 if rotation_weight_m is None else float(rotation_weight_m)
    x0 = np.concatenate([p for _, p in blocks]) if blocks else np.zeros(0)
    x, prior = x0, None
    for _ in range(1 if rotation_weight_m is not None and prior_std is None else 2):
        x = _solve(model, obs, blocks, x, w, max_nfev, prior)
        E = residual_matrix(model, obs, _split(x, blocks))
        s_pos, s_rot = np.sqrt(np.mean(E[:, :3] ** 2)), np.sqrt(np.mean(E[:, 3:] ** 2))
        if rotation_weight_m is None:
            w = float(s_pos / s_rot) if s_rot > 0 and s_pos > 0 else 1.0
        if prior_std is not None and prior is None:  # the noise: what the free fit leaves
            prior = (np.zeros_like(x0), np.asarray(prior_std, dtype=float), max(s_pos, 1e-12))
    fitted = _split(x, blocks)
    J = jacobian(model, obs, fitted, w)
    E = residual_matrix(model, obs, fitted)
    r, J_post = _weighted(E, w), J
    if prior is not None:
        r_prior, J_prior = _prior_rows(x, *prior)
        J_post, r = np.concatenate([J, J_prior]), np.concatenate([r, r_prior])
    dof = max(r.size - x.size, 1)
    rss = float(r @ r)
    cov = rss / dof * np.linalg.pinv(J_post.T @ J_post) if x.size else np.zeros((0, 0))
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    return FitResult(
        params=[p for _, p in fitted],
        std=[s for _, s in _split(std, blocks)],
        cov=cov,
        jac=J,
        residual=E,
        rss=rss,
        dof=dof,
        rotation_weight_m=w,
    )


def _prior_rows(
    x: np.ndarray, centre: np.ndarray, std: np.ndarray, s_p: float
) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``s_p (x - centre) / std`` of a Gaussian prior and their Jacobian (diagonal); a
    parameter with an infinite ``std`` has no prior and no row."""
    held = np.isfinite(std)
    return s_p * (x - centre)[held] / std[held], np.diag(s_p / std)[held]


def _solve(model, obs, blocks, x0, w, max_nfev, prior=None) -> np.ndarray:
    """Least squares from ``x0``; ``prior`` ``(centre, std, s_p)`` adds a Gaussian prior's rows."""
    if x0.size == 0:
        return x0
    steps: dict[tuple[int, int], float] = {}

    def fun(x):
        r = _weighted(residual_matrix(model, obs, _split(x, blocks)), w)
        return r if prior is None else np.concatenate([r, _prior_rows(x, *prior)[0]])

    def jac(x):
        J = jacobian(model, obs, _split(x, blocks), w, steps=steps)
        return J if prior is None else np.concatenate([J, _prior_rows(x, *prior)[1]])

    sol = least_squares(fun, x0, jac=jac, x_scale="jac", method="trf", max_nfev=max_nfev)
    return sol.x
