"""The training loop of :class:`~learner.model.ErrorModel`: mini-batch Adam on the evidential
loss, the learning rate cut on a plateau, early stopping on a validation set; or, for a
continual update's fixed budget, the rate annealed to 0 along a half cosine (a constant
fine-tuning rate left the published weights jittering: BENCHMARKS.md, "Continual updates
annealed").

The validation score is the MSE of the mean the model serves (the network's ``gamma`` weighed
by its epistemic variance, :func:`~learner.evidential.served_mean`), not of ``gamma`` itself:
the two part where the network is unsure, and on 600 real UR10 points the raw ``gamma``'s error
rose while the served one fell, stopping two seeds of six at epoch 34 and 136 (0.34 and
0.26 mm against 0.19-0.22 mm; BENCHMARKS.md, "Early stopping on the mean the model serves").
The best weights by that score are kept, but the run stops only once neither it nor the raw
mean's score has improved for ``early_stop_patience`` epochs: one head's epistemic variance can
flare up for a hundred epochs, and the served score alone stopped two of three seeds on the
simulated paper campaign early (0.097 / 0.082 mm against 0.024 mm).

:meth:`ErrorModel.fit <learner.model.ErrorModel.fit>` scales the points and calls a
:data:`Trainer`: :func:`train_loop` in this process, or a
:class:`~learner.train_process.TrainProcess` that runs it in a child process.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import torch
from threadpoolctl import threadpool_limits

from learner.config import ModelConfig, TrainConfig
from learner.evidential import evidential_elements, served_mean


def set_compute_threads(n: int) -> None:
    """Run torch's intra-op work and numpy/scipy's BLAS on ``n`` threads in this process.

    Small MLPs train fastest on one thread, and idle BLAS threads spin: on two cores, ``make
    demo``'s daemon (its BLAS left at two threads) took 157-162 s against 144-146 s capped."""
    torch.set_num_threads(n)
    threadpool_limits(limits=n, user_api="blas")


#: Gradients are clipped to this total norm (scaled units); a non-finite norm skips the step.
_MAX_GRAD_NORM = 100.0


@dataclass(frozen=True, kw_only=True)
class TrainReport:
    """What one call of :meth:`ErrorModel.fit` did (val MSE in scaled label units)."""

    epochs: int
    best_epoch: int
    best_val_mse: float
    final_train_loss: float
    final_lr: float
    skipped_steps: int
    train_time_s: float
    val_mse_history: tuple[float, ...] = field(default=(), repr=False)


class Trainable(Protocol):
    """What the loop trains: an :class:`~learner.model.ErrorModel`'s network and configs."""

    net: torch.nn.Module
    model_cfg: ModelConfig
    train_cfg: TrainConfig
    skipped_steps: int

    def predict_scaled(self, Xs: torch.Tensor) -> tuple[torch.Tensor, ...]: ...


#: What runs a training loop: called as :func:`train_loop` is, with the scaled tensors of
#: :meth:`ErrorModel.fit`, and trains ``model.net`` in place.
Trainer = Callable[..., TrainReport]


def train_loop(
    model: Trainable,
    Xs: torch.Tensor,
    Ys: torch.Tensor,
    val: tuple[torch.Tensor, torch.Tensor] | None,
    gen: torch.Generator,
    max_epochs: int,
    lr: float,
    on_epoch: Callable[[int, float], None] | None,
    anneal: bool = False,
) -> TrainReport:
    """Mini-batch Adam; a step whose loss or gradient is not finite is skipped and counted.
    With ``anneal`` the rate falls along a half cosine to 0 over ``max_epochs``, a fixed budget
    (a continual update), instead of being cut on plateaus, and nothing stops it early."""
    cfg = model.train_cfg
    net = model.net
    params = list(net.parameters())
    opt = torch.optim.Adam(params, lr=lr, weight_decay=cfg.weight_decay, foreach=True)
    if anneal:
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max_epochs)
    else:
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt, mode="min", factor=0.75, patience=cfg.patience_lr
        )
    start = time.perf_counter()
    n = Xs.shape[0]
    bs = min(cfg.batch_size, n)
    Y_heads = Ys.repeat(1, model.model_cfg.members)  # every member learns every component
    best, best_epoch, best_state = float("inf"), 0, None
    best_mean, progress = float("inf"), 0  # the raw mean's best score; the last epoch either fell
    history: list[float] = []
    skipped = 0
    epoch_loss = float("nan")
    epoch = 0
    for epoch in range(1, max_epochs + 1):
        net.train()
        perm = torch.randperm(n, generator=gen)
        total, count = 0.0, 0
        for i in range(0, n, bs):
            idx = perm[i : i + bs]
            gamma, nu, alpha, beta = net(Xs[idx])
            loss = evidential_elements(
                Y_heads[idx], gamma, nu, alpha, beta, cfg.lam, cfg.nll_variance_power
            ).mean()
            opt.zero_grad(set_to_none=True)
            if not torch.isfinite(loss):
                skipped += 1
                continue
            loss.backward()
            if not torch.isfinite(torch.nn.utils.clip_grad_norm_(params, _MAX_GRAD_NORM)):
                skipped += 1
                continue
            opt.step()
            total += float(loss.detach()) * idx.numel()
            count += idx.numel()
        epoch_loss = total / count if count else float("nan")
        score = epoch_loss
        if val is not None:  # the error of what the model serves, and of the network's own mean
            nig = model.predict_scaled(val[0])
            score = float(((served_mean(*nig) - val[1]) ** 2).mean())
            mean_score = float(((nig[0] - val[1]) ** 2).mean())
            if mean_score < best_mean:
                best_mean, progress = mean_score, epoch
        history.append(score)
        if score < best:
            best, best_epoch, progress = score, epoch, epoch
            if val is not None:
                best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        if anneal:
            sched.step()
        else:
            sched.step(score if np.isfinite(score) else float("inf"))
        if on_epoch is not None:
            on_epoch(epoch, score)
        if val is not None and not anneal and epoch - progress >= cfg.early_stop_patience:
            break
    if best_state is not None:
        net.load_state_dict(best_state)
    model.skipped_steps += skipped
    net.eval()
    return TrainReport(
        epochs=epoch,
        best_epoch=best_epoch,
        best_val_mse=best,
        final_train_loss=epoch_loss,
        final_lr=opt.param_groups[0]["lr"],
        skipped_steps=skipped,
        train_time_s=time.perf_counter() - start,
        val_mse_history=tuple(history),
    )
