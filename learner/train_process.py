"""Training in a child process, so that a daemon's stages keep the interpreter meanwhile.

A daemon's stages are threads of one Python process and take turns on its interpreter lock; a
model update (seconds of small tensor operations) then shares one core with thousands of
messages a second, and the second core of a line PC idles. :class:`TrainProcess` is a
:data:`~learner.training.Trainer` that runs :func:`~learner.training.train_loop` in a child
interpreter (``python -m learner.train_process``) instead, while the calling thread waits
without the lock.

Requests and replies are safetensors blobs on the child's stdin and stdout, each after its
length (8 bytes, little-endian), never pickle: the model goes as its snapshot, the scaled
points and the random generator's state as tensors, the rest as JSON metadata; the trained
weights, the generator's new state and the :class:`~learner.training.TrainReport` come back.
The child runs the same operations with the same thread count and draws, so the weights are
the ones :func:`~learner.training.train_loop` gives in the caller's process. Should the child
die or fail, that update trains in the caller's process and a new child starts next time.
Usage: ``model.fit(X, Y, trainer=TrainProcess())``; ``close()`` ends the child, and so does
the caller's death (the child watches its parent).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import BinaryIO

import torch
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from learner.model import ErrorModel
from learner.snapshot import read_metadata, snapshot_from_bytes, snapshot_to_bytes
from learner.training import TrainReport, set_compute_threads, train_loop

_KEY = "robocal.train"
#: Failures in a row after which the caller's process trains from then on (a child that cannot
#: even start would otherwise cost an interpreter start per update).
MAX_FAILURES_IN_A_ROW = 3
_ROOT = Path(__file__).resolve().parents[1]  # the child imports this very code


class TrainProcess:
    """A :data:`~learner.training.Trainer` whose loop runs in a child process (module
    docstring); one call at a time. ``on_failure(reason)`` hears of a child that ended, died
    during an update (which then trains here) or failed; ``failures`` counts them. After
    :data:`MAX_FAILURES_IN_A_ROW` the caller's process trains from then on."""

    def __init__(self, on_failure: Callable[[str], None] | None = None) -> None:
        self.on_failure = on_failure
        self.failures = 0
        self.trained = 0  # training runs the child answered
        self._in_a_row = 0
        self._lock = threading.Lock()
        self._proc: subprocess.Popen | None = None
        self._closed = False
        self._start()

    @property
    def pid(self) -> int | None:
        """The child's process id (None after :meth:`close`)."""
        return None if self._proc is None else self._proc.pid

    def _start(self) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(_ROOT), env.get("PYTHONPATH")]))
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "learner.train_process"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
        )
        weakref.finalize(self, self._proc.kill)  # a dropped, unclosed trainer ends its child

    def __call__(
        self,
        model: ErrorModel,
        Xs: torch.Tensor,
        Ys: torch.Tensor,
        val: tuple[torch.Tensor, torch.Tensor] | None,
        gen: torch.Generator,
        max_epochs: int,
        lr: float,
        on_epoch: Callable[[int, float], None] | None = None,
        anneal: bool = False,
    ) -> TrainReport:
        """Train ``model.net`` in place as :func:`~learner.training.train_loop` does. With
        ``on_epoch`` (which may stop training by raising) the loop runs here."""
        if on_epoch is not None:
            return train_loop(model, Xs, Ys, val, gen, max_epochs, lr, on_epoch, anneal)
        job = {
            "max_epochs": max_epochs,
            "lr": lr,
            "anneal": anneal,
            "threads": torch.get_num_threads(),
        }
        tensors = {"x": Xs, "y": Ys, "gen_state": gen.get_state()}
        if val is not None:
            tensors["val_x"], tensors["val_y"] = val
        tensors["snapshot"] = torch.frombuffer(
            bytearray(snapshot_to_bytes(model)), dtype=torch.uint8
        )
        request = st_save(
            {k: v.contiguous() for k, v in tensors.items()}, metadata={_KEY: json.dumps(job)}
        )
        with self._lock:
            reply = None if self._closed else self._ask(request)
        answer = {} if reply is None else read_metadata(reply, _KEY)
        if "error" in answer:
            self._failed(f"training failed in its process ({answer['error']}); trains here")
        elif reply is not None:
            weights = st_load(reply)
            gen.set_state(weights.pop("gen_state"))
            model.net.load_state_dict(weights, strict=True)
            model.net.eval()
            model.skipped_steps += answer["skipped_steps"]
            self.trained += 1
            self._in_a_row = 0
            return TrainReport(**answer | {"val_mse_history": tuple(answer["val_mse_history"])})
        return train_loop(model, Xs, Ys, val, gen, max_epochs, lr, on_epoch, anneal)

    def _ask(self, request: bytes) -> bytes | None:
        """The child's reply (a new child if the last one ended), or None if it was lost."""
        if self._proc is not None and self._proc.poll() is not None:
            ended, self._proc = self._proc, None
            self._failed(f"training process ended (exit code {ended.returncode})")
        if self._closed:
            return None
        if self._proc is None:
            self._start()
        proc = self._proc  # close() from another thread may take it meanwhile
        try:
            _write_frame(proc.stdin, request)
            reply = _read_frame(proc.stdout)
        except (OSError, ValueError) as exc:  # ValueError: a pipe close() closed
            reply, reason = None, str(exc)
        else:
            reason = "it ended"
        if reply is None:
            proc.kill()
            if self._proc is proc:
                self._proc = None
            self._failed(
                f"training process lost ({reason}, exit code {proc.wait()}); "
                "this update trains in the caller's process"
            )
        return reply

    def _failed(self, reason: str) -> None:
        self.failures += 1
        self._in_a_row += 1
        if self._in_a_row >= MAX_FAILURES_IN_A_ROW:
            self.close()
            reason += f"; {self._in_a_row} failures in a row: training here from now on"
        if self.on_failure is not None:
            self.on_failure(reason)

    def close(self) -> None:
        """End the child (it holds nothing that needs saving); later calls train here."""
        self._closed = True
        proc, self._proc = self._proc, None
        if proc is not None:
            proc.kill()
            proc.wait()
            for pipe in (proc.stdin, proc.stdout):
                pipe.close()


def _write_frame(out: BinaryIO, data: bytes) -> None:
    out.write(len(data).to_bytes(8, "little"))
    out.write(data)
    out.flush()


def _read_frame(inp: BinaryIO) -> bytes | None:
    """The next frame, or None at the end of the stream (also inside a frame)."""
    head = inp.read(8)
    if len(head) < 8:
        return None
    data = inp.read(int.from_bytes(head, "little"))
    return data if len(data) == int.from_bytes(head, "little") else None


def _answer(request: bytes) -> bytes:
    """The child's reply to one request: the trained weights and report, or the error."""
    try:
        job = read_metadata(request, _KEY)
        tensors = st_load(request)
        model = snapshot_from_bytes(tensors.pop("snapshot").numpy().tobytes())
        set_compute_threads(int(job["threads"]))
        gen = torch.Generator()
        gen.set_state(tensors["gen_state"])
        val = (tensors["val_x"], tensors["val_y"]) if "val_x" in tensors else None
        epochs, lr, anneal = int(job["max_epochs"]), float(job["lr"]), bool(job["anneal"])
        report = train_loop(model, tensors["x"], tensors["y"], val, gen, epochs, lr, None, anneal)
    except Exception as exc:  # noqa: BLE001 - reported to the caller, which trains itself
        return st_save({}, metadata={_KEY: json.dumps({"error": f"{type(exc).__name__}: {exc}"})})
    weights = {k: v.contiguous() for k, v in model.net.state_dict().items()}
    weights["gen_state"] = gen.get_state()
    return st_save(weights, metadata={_KEY: json.dumps(asdict(report))})


def _end_with(parent: int, poll_s: float = 1.0) -> None:
    """End this process once ``parent`` is no longer its parent: a daemon killed mid-fit (kill
    -9, or abandoned at its shutdown timeout) leaves no child training on for minutes."""
    while os.getppid() == parent:
        time.sleep(poll_s)
    os._exit(1)


def main() -> None:
    """The child: answer requests on stdin until it closes, or end within a second of its
    parent. Its own stdout carries only the replies (anything a library prints goes to
    stderr)."""
    threading.Thread(target=_end_with, args=(os.getppid(),), daemon=True).start()
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    while (request := _read_frame(sys.stdin.buffer)) is not None:
        _write_frame(replies, _answer(request))


if __name__ == "__main__":
    main()
