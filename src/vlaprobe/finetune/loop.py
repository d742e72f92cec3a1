"""The training loop: AdamW, warm-up + cosine, gradient clipping; evaluation, metrics and checkpoints.

Everything random is a function of the seed and the step (the epoch's sample order, each step's
augmentation), so a run resumed from a checkpoint takes exactly the steps an uninterrupted run takes.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from vlaprobe.configs.finetune import FinetuneConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject
from vlaprobe.finetune.data import Split
from vlaprobe.finetune.evaluate import autocast, validate
from vlaprobe.finetune.examples import ActionStats, Examples, make_batch
from vlaprobe.finetune.objective import Batch, StepForward
from vlaprobe.finetune.state import TrainState, write_checkpoint, write_metrics
from vlaprobe.policies.openvla.model import ACTION_DIM, OpenVLA

AUGMENT_STREAM = 1_000_003
"""Generator key that keeps the augmentation draws apart from the sample order's."""


def lr_at(step: int, total: int, cfg: FinetuneConfig) -> float:
    """Learning rate of optimizer step ``step`` (0-based): linear warm-up, then cosine to ``min_lr_ratio``."""
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    progress = (step - cfg.warmup_steps) / max(1, total - cfg.warmup_steps)
    cosine = 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))
    return cfg.lr * (cfg.min_lr_ratio + (1 - cfg.min_lr_ratio) * cosine)


@dataclass
class Schedule:
    """How many steps, and when to evaluate."""

    steps_per_epoch: int
    """Full batches per pass over the training rows (the last partial batch is dropped)."""
    total: int
    """Optimizer steps of the whole run."""
    eval_every: int
    """Steps between evaluations (and checkpoints)."""


def make_schedule(cfg: FinetuneConfig, train_rows: int) -> Schedule:
    per_epoch = train_rows // cfg.batch_size
    total = cfg.max_steps if cfg.max_steps is not None else cfg.epochs * per_epoch
    return Schedule(per_epoch, total, cfg.eval_every or per_epoch)


@dataclass
class Trainer:
    """What one training run holds."""

    cfg: FinetuneConfig
    model: OpenVLA
    examples: Examples
    split: Split
    stats: ActionStats
    device: torch.device
    schedule: Schedule
    optimizer: torch.optim.Optimizer
    write_model: Callable[[Path], None]
    adapter: Callable[[], tuple[dict[str, torch.Tensor], JsonObject]] | None
    records: list[JsonObject]
    """Metric records so far (those of a resumed checkpoint first)."""
    state: TrainState
    forward: StepForward
    """Batch → (label logits, loss): :func:`vlaprobe.finetune.objective.step_forward`, compiled or not."""
    _epoch: int = field(default=-1, init=False)
    _order: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), init=False)

    def rows(self, step: int) -> np.ndarray:
        """The training rows of optimizer step ``step``: one slice of its epoch's seeded permutation."""
        epoch, index = divmod(step, self.schedule.steps_per_epoch)
        if self._epoch != epoch:
            self._epoch = epoch
            self._order = self.split.train[
                np.random.default_rng([self.cfg.seed, epoch]).permutation(len(self.split.train))
            ]
        bs = self.cfg.batch_size
        return self._order[index * bs : (index + 1) * bs]

    def step(self) -> tuple[float, float]:
        """One optimizer step; returns its loss and its batch's action-token accuracy (before the update)."""
        cfg, step = self.cfg, self.state.step
        rng = np.random.default_rng([cfg.seed, AUGMENT_STREAM, step]) if cfg.augment else None
        batch = make_batch(self.examples, self.rows(step), self.model, self.device, rng, cfg.crop_scale)
        for group in self.optimizer.param_groups:
            group["lr"] = lr_at(step, self.schedule.total, cfg)
        with autocast(self.device, cfg.bf16):
            logits, loss = self._forward(batch)
        hits = logits[:, :ACTION_DIM].detach().argmax(-1) == batch.labels[:, :ACTION_DIM]
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            params = [p for g in self.optimizer.param_groups for p in g["params"]]
            torch.nn.utils.clip_grad_norm_(params, cfg.grad_clip)
        self.optimizer.step()
        self.state.step += 1
        return float(loss.detach()), float(hits.float().mean())

    def _forward(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
        try:
            return self.forward(batch)
        except torch._dynamo.exc.BackendCompilerFailed as e:
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise VlaprobeError(
                f"--compile failed to compile the training step ({first[:200]}); run without --compile"
            ) from None

    def evaluate(self, scheduled: bool, rate: float) -> JsonObject:
        """Validate, append the record to ``metrics.jsonl`` and write a checkpoint (in that order)."""
        s = self.state
        v = validate(
            self.model,
            self.examples,
            self.split.val,
            self.stats,
            self.device,
            self.cfg.batch_size,
            self.cfg.bf16,
        )
        record: JsonObject = {
            "step": s.step,
            "epoch": round(s.step / self.schedule.steps_per_epoch, 4),
            "lr": lr_at(max(0, s.step - 1), self.schedule.total, self.cfg),
            "train_loss": s.loss_sum / max(1, s.loss_count),
            "train_accuracy": s.accuracy_sum / max(1, s.loss_count),
            "val_loss": v.loss,
            "val_accuracy": v.accuracy,
            "val_l1": v.l1,
            "val_l1_normalized": v.l1_normalized,
            "val_samples": v.samples,
            "elapsed_s": round(s.elapsed_s, 1),
            "samples_per_s": round(rate, 2),
        }
        if not scheduled:
            record["stopped"] = "max_minutes"
        self.records.append(record)
        out = self.cfg.out
        write_metrics(out, self.records)
        if scheduled:  # a stop's record does not restart the running training loss
            s.loss_sum, s.accuracy_sum, s.loss_count = 0.0, 0.0, 0
        write_checkpoint(out, self.write_model, s, self.optimizer, self.adapter() if self.adapter else None)
        return record

    def run(self) -> bool:
        """Train to the end or to ``max_minutes``; True when the run finished."""
        from tqdm import tqdm

        cfg, s = self.cfg, self.state
        self.model.train()
        start = time.monotonic()
        base_elapsed = s.elapsed_s
        mark_time, mark_step = start, s.step
        bar = tqdm(
            total=self.schedule.total, initial=s.step, disable=not cfg.progress, unit="step", desc="finetune"
        )
        try:
            while s.step < self.schedule.total:
                loss, accuracy = self.step()
                s.loss_sum += loss
                s.accuracy_sum += accuracy
                s.loss_count += 1
                now = time.monotonic()
                s.elapsed_s = base_elapsed + now - start
                bar.update(1)
                bar.set_postfix(loss=f"{loss:.3f}")
                scheduled = s.step % self.schedule.eval_every == 0 or s.step == self.schedule.total
                out_of_time = cfg.max_minutes is not None and now - start >= cfg.max_minutes * 60
                if scheduled or out_of_time:
                    rate = (s.step - mark_step) * cfg.batch_size / max(1e-9, now - mark_time)
                    record = self.evaluate(scheduled, rate)
                    bar.write(_line(record))
                    mark_time, mark_step = time.monotonic(), s.step
                    if out_of_time and s.step < self.schedule.total:
                        return False
        finally:
            bar.close()
        return True


def _line(record: JsonObject) -> str:
    return (
        f"step {record['step']}: train loss {record['train_loss']:.4f}, train token accuracy "
        f"{record['train_accuracy']:.4f}, val loss {record['val_loss']:.4f}, "
        f"val token accuracy {record['val_accuracy']:.4f}, val L1 {record['val_l1']:.4f}"
    )
