"""All cross-validation folds of a trial trained at once, as one batched ensemble.

:class:`~learner.ensemble.EvidentialEnsemble` already evaluates its heads as batched weight
tensors ``(H, in, out)``; here a trial's ``K`` folds become ``K`` groups of heads of one such
ensemble (head ``k * 6 * members + m * 6 + c``: fold ``k``, member ``m``, component ``c``). Each
step, every fold's heads get ``batch_size`` of that fold's own training rows (each fold shuffles
its rows every epoch; a head's rows enter its first layer through one ``baddbmm``), so a fold
never sees its validation rows and no row is computed for nothing. Everything else that couples
parameters is per fold too: label scaling, gradient-norm clipping, the Adam learning rate and
its plateau cut, skipped non-finite steps and early stopping. Each fold therefore trains as
:meth:`learner.model.ErrorModel.fit` would train it alone (same rules, other random draws), in
one pass instead of ``K``.

Small networks run faster this way (per-step overhead is shared by the folds); networks whose
step is bound by memory traffic over their weights gain nothing (BENCHMARKS.md,
"Hyperparameter search").
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch.nn import functional as F  # noqa: N812

from learner.base import PhysicsBase
from learner.config import ModelConfig, TrainConfig
from learner.ensemble import EvidentialEnsemble
from learner.evidential import combine_members, evidential_elements, served_mean
from learner.features import FeatureSpec
from learner.model import N_LABELS, ErrorModel

_ACTIVATIONS = {"elu": F.elu, "relu": F.relu, "gelu": F.gelu}
_FLOOR = 1e-6  # as learner.ensemble

#: Gradients are clipped per fold to this total norm (as :mod:`learner.model` does per model).
MAX_GRAD_NORM = 100.0
_BETAS = (0.9, 0.999)
_EPS = 1e-8
_PLATEAU_FACTOR = 0.75
_PLATEAU_THRESHOLD = 1e-4  # relative, as torch's ReduceLROnPlateau default


@dataclass(frozen=True, kw_only=True)
class FoldsReport:
    """What :func:`train_folds` did: per fold the minimum validation MSE over epochs (scaled
    label units) and the epoch it came at, the epochs run, the wall time (s) and the batched
    network as it ended (fold ``k``'s heads: ``k * 6 * members`` onwards)."""

    min_val_mse: tuple[float, ...]
    best_epochs: tuple[int, ...]
    epochs: int
    train_time_s: float
    net: EvidentialEnsemble | None = field(default=None, repr=False, compare=False)


def train_folds(
    spec: FeatureSpec,
    X: np.ndarray,
    Y: np.ndarray,
    folds: list[np.ndarray],
    model_cfg: ModelConfig,
    train_cfg: TrainConfig,
    *,
    seed: int,
    base: PhysicsBase | None = None,
    on_epoch: Callable[[int, np.ndarray], None] | None = None,
    deadline: float | None = None,
) -> FoldsReport:
    """Train one residual network per fold on ``base`` (validation rows ``folds[k]``), all in
    one batched ensemble, for ``train_cfg.max_epochs`` at most.

    ``X`` are raw SI features ``(N, F)``, ``Y`` pose-error labels ``(N, 6)`` (m, rad).
    ``on_epoch(epoch, running_min)`` gets every fold's minimum validation MSE so far ``(K,)``
    and may raise (e.g. ``optuna.TrialPruned``) to stop; the exception propagates. Past
    ``deadline`` (``time.monotonic()``, s) the next step raises ``TimeoutError``.
    """
    start = time.perf_counter()
    K, M = len(folds), model_cfg.members
    per_fold = N_LABELS * M
    probe = ErrorModel.create(spec, model_cfg, train_cfg, seed=seed, base=base)
    Xs = probe.scale_x(X)
    R = np.asarray(Y, dtype=float) - probe.base_error(X)  # the networks learn what the base leaves
    n = len(X)
    train_mask = np.ones((n, K), dtype=bool)
    for k, val in enumerate(folds):
        train_mask[val, k] = False
    Ys = np.empty((n, K, N_LABELS))
    for k in range(K):
        rows = R[train_mask[:, k]]
        std = rows.std(axis=0)
        Ys[:, k] = (R - rows.mean(axis=0)) / np.where(std > 1e-12, std, 1.0)
    Yt = torch.as_tensor(Ys, dtype=torch.float32)  # (N, K, 6)
    validation = _FoldValidation(Xs, Yt, folds, M)
    train_rows = [torch.as_tensor(np.flatnonzero(train_mask[:, k])) for k in range(K)]
    width = max(r.numel() for r in train_rows)
    fold_index = torch.arange(K)[:, None]
    act = _ACTIVATIONS[model_cfg.activation]
    net = EvidentialEnsemble(
        n_inputs=Xs.shape[1],
        hidden_layers=model_cfg.hidden_layers,
        neurons=model_cfg.neurons,
        activation=model_cfg.activation,
        dropout=model_cfg.dropout,
        n_heads=K * per_fold,
        seed=seed,
    )
    opt = _FoldAdam(list(net.parameters()), K, per_fold, train_cfg.lr, train_cfg.weight_decay)
    gen = torch.Generator().manual_seed(train_cfg.seed + seed)
    bs = min(train_cfg.batch_size, width)
    best = np.full(K, np.inf)
    best_epoch = np.zeros(K, dtype=int)
    best_mean = np.full(K, np.inf)  # the raw mean's score; the last epoch either score fell
    progress = np.zeros(K, dtype=int)
    plateau_best = np.full(K, np.inf)
    bad = np.zeros(K, dtype=int)
    active = np.ones(K, dtype=bool)
    epoch = 0
    for epoch in range(1, train_cfg.max_epochs + 1):
        order, weight = _epoch_order(train_rows, width, gen)
        for i in range(0, width, bs):
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"deadline passed in epoch {epoch}")
            rows, w = order[:, i : i + bs], weight[:, i : i + bs]  # (K, b)
            b = rows.shape[1]
            x = Xs[rows].repeat_interleave(per_fold, dim=0)  # (H, b, F): each head its rows
            y = Yt[rows, fold_index].transpose(1, 2).unsqueeze(1).expand(K, M, N_LABELS, b)
            y = y.reshape(K * per_fold, b)
            gamma, nu, alpha, beta = _nig(_forward(net, x, act, model_cfg.dropout, True))
            elem = evidential_elements(
                y, gamma, nu, alpha, beta, train_cfg.lam, train_cfg.nll_variance_power
            )
            counts = w.sum(dim=1).clamp(min=1.0) * per_fold
            per_head = (elem * w.repeat_interleave(per_fold, dim=0)).sum(dim=1)
            fold_loss = per_head.view(K, per_fold).sum(dim=1) / counts
            opt.zero_grad()
            finite = torch.isfinite(fold_loss)
            torch.where(finite, fold_loss, torch.zeros_like(fold_loss)).sum().backward()
            opt.step(finite & torch.as_tensor(active))
        val, val_mean = validation.mse(net, model_cfg.activation)
        for k in np.flatnonzero(active):
            score = val[k] if math.isfinite(val[k]) else math.inf
            if score < best[k]:
                best[k], best_epoch[k], progress[k] = score, epoch, epoch
            if val_mean[k] < best_mean[k]:  # the network's own mean still learns
                best_mean[k], progress[k] = val_mean[k], epoch
            if score < plateau_best[k] * (1.0 - _PLATEAU_THRESHOLD):
                plateau_best[k], bad[k] = score, 0
            else:
                bad[k] += 1
                if bad[k] > train_cfg.patience_lr:
                    opt.lr[k] *= _PLATEAU_FACTOR
                    bad[k] = 0
            if epoch - progress[k] >= train_cfg.early_stop_patience:
                active[k] = False
        if on_epoch is not None:
            on_epoch(epoch, best.copy())
        if not active.any():
            break
    return FoldsReport(
        min_val_mse=tuple(float(b) for b in best),
        best_epochs=tuple(int(e) for e in best_epoch),
        epochs=epoch,
        train_time_s=time.perf_counter() - start,
        net=net,
    )


def _epoch_order(
    train_rows: list[torch.Tensor], width: int, gen: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each fold's training rows in a fresh random order ``(K, width)``, padded (weight 0) to
    the largest fold, and the weights ``(K, width)``."""
    order = torch.zeros((len(train_rows), width), dtype=torch.long)
    weight = torch.zeros((len(train_rows), width))
    for k, rows in enumerate(train_rows):
        order[k, : rows.numel()] = rows[torch.randperm(rows.numel(), generator=gen)]
        weight[k, : rows.numel()] = 1.0
    return order, weight


def _forward(
    net: EvidentialEnsemble, x: torch.Tensor, act: Callable, dropout: float, training: bool
) -> torch.Tensor:
    """Raw outputs ``(H, b, 4)`` of every head on its own rows ``x`` ``(H, b, F)``."""
    h = x
    last = len(net.weights) - 1
    for i, (w, b) in enumerate(zip(net.weights, net.biases, strict=True)):
        h = torch.baddbmm(b, h, w)
        if i < last:
            h = act(h)
            if dropout > 0.0 and training:
                h = F.dropout(h, dropout, True)
    return h


def _nig(out: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """``gamma, nu, alpha, beta`` from raw outputs, as :class:`EvidentialEnsemble` makes them."""
    return (
        out[..., 0],
        F.softplus(out[..., 1]) + _FLOOR,
        F.softplus(out[..., 2]) + (1.0 + _FLOOR),
        F.softplus(out[..., 3]) + _FLOOR,
    )


class _FoldValidation:
    """Each fold's heads evaluated on that fold's validation rows only (padded to the largest
    fold; a fifth of evaluating every row with every head at five folds)."""

    def __init__(
        self, Xs: torch.Tensor, target: torch.Tensor, folds: list[np.ndarray], M: int
    ) -> None:
        """``target``: scaled residual labels per fold ``(N, K, 6)``."""
        K, width = len(folds), max(f.size for f in folds)
        rows = np.zeros((K, width), dtype=np.int64)
        valid = np.zeros((K, width), dtype=np.float32)
        for k, f in enumerate(folds):
            rows[k, : f.size], valid[k, : f.size] = f, 1.0
        per_fold = N_LABELS * M
        self.K, self.M = K, M
        # (H, width, F): fold k's rows for each of its heads
        self.x = Xs[torch.as_tensor(rows)].repeat_interleave(per_fold, dim=0)
        self.y = torch.stack([target[torch.as_tensor(rows[k]), k] for k in range(K)])  # (K, W, 6)
        self.valid = torch.as_tensor(valid)
        self.count = self.valid.sum(dim=1)

    def mse(self, net: EvidentialEnsemble, activation: str) -> tuple[np.ndarray, np.ndarray]:
        """Per fold the validation MSE ``(K,)`` of the mean the members serve together
        (:func:`~learner.evidential.served_mean`, scaled units) and of their own mean
        ``gamma``, as ``train_loop`` scores."""
        with torch.inference_mode():
            h = _forward(net, self.x, _ACTIVATIONS[activation], 0.0, False)
            K, W = self.K, h.shape[1]
            # (K * M * 6, W) heads -> (K * W, M * 6) rows of member-major heads, as a net outputs
            nig = (t.reshape(K, -1, W).transpose(1, 2).reshape(K * W, -1) for t in _nig(h))
            combined = combine_members(*nig, self.M)
            scores = []
            for mean in (served_mean(*combined), combined[0]):
                sq = (mean.view(K, W, N_LABELS) - self.y).square().mean(dim=2)  # (K, W)
                scores.append(((sq * self.valid).sum(dim=1) / self.count).double().numpy())
        return scores[0], scores[1]


class _FoldAdam:
    """Adam (L2 weight decay as ``torch.optim.Adam``) over parameters whose first dimension is
    the head, with one learning rate per fold of ``per_fold`` heads, per-fold gradient-norm
    clipping, and per-fold skipping of a step (non-finite loss or gradient, or a stopped fold)."""

    def __init__(
        self, params: list[torch.Tensor], folds: int, per_fold: int, lr: float, decay: float
    ) -> None:
        self.params = params
        self.folds, self.per_fold = folds, per_fold
        self.lr = np.full(folds, lr)
        self.decay = decay
        self.exp_avg = [torch.zeros_like(p) for p in params]
        self.exp_avg_sq = [torch.zeros_like(p) for p in params]
        self._buf = [torch.empty_like(p) for p in params]
        self.steps = np.zeros(folds, dtype=int)

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    def step(self, allowed: torch.Tensor) -> None:
        """One Adam step for the folds ``allowed`` ``(K,) bool`` whose gradient is finite."""
        grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in self.params]
        sq = sum(torch.linalg.vector_norm(g.flatten(1), dim=1).square() for g in grads)
        norm = sq.view(self.folds, self.per_fold).sum(dim=1).sqrt()  # (K,)
        ok = allowed & torch.isfinite(norm)
        if not bool(ok.any()):
            return
        clip = torch.where(ok, (MAX_GRAD_NORM / (norm + 1e-6)).clamp(max=1.0), 0.0)
        ok_np = ok.numpy()
        self.steps += ok_np
        b1, b2 = _BETAS
        t = np.maximum(self.steps, 1)
        step_size = np.where(ok_np, self.lr / (1.0 - b1**t), 0.0)
        head = lambda v: torch.as_tensor(v, dtype=torch.float32).repeat_interleave(  # noqa: E731
            self.per_fold
        )
        size_h, clip_h = head(step_size), head(clip)
        bc2_h = head(np.sqrt(1.0 - b2**t))
        every = bool(ok.all())
        clipped = bool((clip < 1.0).any())
        keep_h = head(ok_np.astype(np.float32))
        with torch.no_grad():  # in place on the gradients and one reused buffer: no big temporaries
            for p, g, m, v, buf in zip(
                self.params, grads, self.exp_avg, self.exp_avg_sq, self._buf, strict=True
            ):
                shape = (-1,) + (1,) * (p.dim() - 1)
                if not every:
                    g.nan_to_num_(nan=0.0, posinf=0.0, neginf=0.0)
                if clipped or not every:
                    g.mul_(clip_h.view(shape))
                if self.decay:
                    g.add_(p, alpha=self.decay)
                if every:  # the usual step
                    m.lerp_(g, 1.0 - b1)
                    v.mul_(b2).addcmul_(g, g, value=1.0 - b2)
                else:  # a skipped fold keeps its moments
                    keep = keep_h.view(shape)
                    m.add_((g - m) * ((1.0 - b1) * keep))
                    v.add_((g.square() - v) * ((1.0 - b2) * keep))
                torch.sqrt(v, out=buf)
                # a skipped fold's step size is 0: m / inf = 0 leaves its weights as they are
                buf.div_(bc2_h.view(shape)).add_(_EPS).div_(size_h.view(shape))
                p.addcdiv_(m, buf, value=-1.0)
