"""The deferred observer: an expert-driven episode observed after it ran, in batches, gives the rows the model
would have given step by step."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from tests.collection.fakes import FakeEnv, FakePolicy, FakeStep, fake_driver, fake_scenes, fake_tasks
from tests.collection.fingerprint import compare, store_fingerprint
from tests.collection.test_collect import config

from vlaprobe.collection.collect import collect
from vlaprobe.collection.worker import Worker
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.policies.base import BatchObserver
from vlaprobe.policies.factory import make_policy
from vlaprobe.rollout import DeferredObserver, StepRecord


class BatchFakePolicy(FakePolicy):
    """The fake model, also able to observe preprocessed images in batches (each as :meth:`step` would)."""

    batches: ClassVar[list[int]] = []

    def model_image(self, image: np.ndarray) -> np.ndarray:
        return image[::-1, ::-1].copy()

    def steps(self, model_images: np.ndarray, instruction: str) -> list[FakeStep]:
        BatchFakePolicy.batches.append(len(model_images))
        return [self.step(m[::-1, ::-1].copy(), instruction) for m in model_images]


def _workers(policy: type) -> partial[Worker]:
    return partial(
        Worker,
        make_env=FakeEnv,
        make_policy=policy,
        make_driver=fake_driver,
        list_tasks=fake_tasks,
        task_scenes=fake_scenes,
    )


@pytest.mark.parametrize("perturb", ["", "drop=1,displace=1"])
def test_an_expert_store_observed_afterwards_equals_one_observed_step_by_step(
    tmp_path: Path, perturb: str
) -> None:
    BatchFakePolicy.batches = []
    collect(config(tmp_path / "steps", perturb=perturb, keep_failed=True), _workers(FakePolicy))
    collect(config(tmp_path / "batches", perturb=perturb, keep_failed=True), _workers(BatchFakePolicy))
    assert BatchFakePolicy.batches, "the batch-capable policy was not deferred"
    expected = store_fingerprint(tmp_path / "steps")
    assert compare(expected, store_fingerprint(tmp_path / "batches")) == []


def test_the_policy_driver_keeps_the_model_in_the_loop(tmp_path: Path) -> None:
    BatchFakePolicy.batches = []
    collect(config(tmp_path / "s", driver="policy"), _workers(BatchFakePolicy))
    assert BatchFakePolicy.batches == []


def test_refuses_a_policy_that_cannot_batch() -> None:
    with pytest.raises(TypeError, match="batches"):
        DeferredObserver(FakePolicy(PolicyConfig()))


def _record(t: int, image: np.ndarray) -> StepRecord:
    nan = np.full(7, np.nan)
    return StepRecord(
        t=t, step=t, raw_image=None, model_image=image, hidden=np.zeros(0), object_atoms=np.zeros(0, bool),
        action_atoms=np.zeros(0, bool), world=None, proprio=None, action=nan, predicted_action=nan,
        action_tokens=None, success=False, terminal=False, perturbed=False, perturbation="", timings=None,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("pooling", "renders"), [("last_prompt", 35), ("action_tokens", 4), ("mean_text", 4)]
)
def test_the_tiny_model_in_batches_matches_its_single_steps(pooling: str, renders: int) -> None:
    """Renders through the shipped observer in batches (35: one of 32 and one of 3): the same tokens and actions,
    hidden states within float32 rounding of the single steps, for every kind of pooling."""
    policy = make_policy(PolicyConfig(model="tiny-libero", device="cpu", pooling=pooling))  # type: ignore[arg-type]
    assert isinstance(policy, BatchObserver)
    deferred = DeferredObserver(policy)
    instruction = "pick up the black bowl next to the plate and place it on the plate"
    images = np.random.default_rng(0).integers(0, 256, (renders, 128, 128, 3), dtype=np.uint8)
    records = [_record(t, deferred.step(r, instruction).model_image) for t, r in enumerate(images)]
    filled = deferred.fill(records, instruction)
    for render, rec in zip(images, filled, strict=True):
        single = policy.step(render, instruction)
        np.testing.assert_array_equal(rec.model_image, single.model_image)
        np.testing.assert_array_equal(rec.action_tokens, single.action_tokens)
        np.testing.assert_array_equal(rec.predicted_action, single.action)
        assert rec.hidden.shape == single.hidden.shape
        np.testing.assert_allclose(rec.hidden, single.hidden, atol=1e-4, rtol=1e-5)
    assert not np.allclose(filled[0].hidden, filled[1].hidden)  # each row its own image's states
