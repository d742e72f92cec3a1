"""The observer of an episode whose driver does not read the model, run after the episode in batches.

Under the scripted expert the model only observes: its hidden states and predicted actions never change what
happens. :class:`DeferredObserver` stands in for the model during the step loop (it only preprocesses each
render) and :meth:`DeferredObserver.fill` then takes the model's steps on the episode's images in batches:
one prompt pass per batch instead of one per step (tiny-libero on 1 CPU thread: ~16 ms per image instead of
~75 ms per step; ``bench/collect_throughput.py``). The policy driver reads the model every step, and so does the
live server: they run the model in the loop.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vlaprobe.files import JsonObject
from vlaprobe.policies.base import BatchObserver, PolicyStep, VLAPolicy
from vlaprobe.rollout.loop import StepRecord

_NO_ACTION = np.full(7, np.nan)
_NO_TOKENS = np.zeros(7, dtype=np.int64)
_NO_HIDDEN = np.zeros((0,), dtype=np.float32)


class DeferredObserver:
    """A :class:`~vlaprobe.policies.base.VLAPolicy` whose steps only preprocess the image; the model observes
    the episode's records afterwards (:meth:`fill`)."""

    def __init__(self, policy: VLAPolicy) -> None:
        if not isinstance(policy, BatchObserver):
            raise TypeError(f"{type(policy).__name__} cannot observe images in batches")
        self.policy: VLAPolicy = policy
        self._batch: BatchObserver = policy
        self.model_id = policy.model_id
        self.num_hidden_states = policy.num_hidden_states
        self.hidden_size = policy.hidden_size
        self.pooling = policy.pooling

    def step(self, image: np.ndarray, instruction: str) -> PolicyStep:
        """The preprocessed image only: no action, no hidden states until :meth:`fill`."""
        return PolicyStep(
            action=_NO_ACTION,
            hidden=_NO_HIDDEN,
            model_image=self._batch.model_image(image),
            action_tokens=_NO_TOKENS,
        )

    def fill(self, records: list[StepRecord], instruction: str) -> list[StepRecord]:
        """The records with the model's hidden states, predicted actions and their tokens filled in."""
        if not records:
            return []
        steps = self._batch.steps(np.stack([r.model_image for r in records]), instruction)
        return [
            dataclasses.replace(r, hidden=s.hidden, predicted_action=s.action, action_tokens=s.action_tokens)
            for r, s in zip(records, steps, strict=True)
        ]

    def describe(self) -> JsonObject:
        return self.policy.describe()
