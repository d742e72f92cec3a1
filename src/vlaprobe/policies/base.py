"""The policy interface the rest of the pipeline sees: one image and instruction in, one action and every
layer's hidden state out, from one step of work.

This module stays light (numpy only) and knows no implementation: ``vlaprobe.policies.factory`` builds them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from vlaprobe.configs.policy import Pooling
from vlaprobe.files import JsonObject


@dataclass
class PolicyStep:
    """One step of a VLA policy."""

    action: np.ndarray
    """(7,) float64, ready for LIBERO's ``env.step``: dx, dy, dz, droll, dpitch, dyaw, gripper (−1 open, +1 close)."""
    hidden: np.ndarray
    """float32; (num_hidden_states, hidden_size), or (num_hidden_states, 7, hidden_size) for "action_tokens"."""
    model_image: np.ndarray
    """(224, 224, 3) uint8: the image exactly as handed to the model (after the LIBERO preprocessing)."""
    action_tokens: np.ndarray
    """(7,) int64: the token ids the action was decoded from."""


@runtime_checkable
class VLAPolicy(Protocol):
    """A vision-language-action model that exposes its hidden states."""

    model_id: str
    """E.g. "tiny-openvla-seed0" or the checkpoint folder's name."""
    num_hidden_states: int
    """Embedding output + one per decoder layer (33 for OpenVLA-7B and the tiny default)."""
    hidden_size: int
    """Width of each hidden state."""
    pooling: Pooling
    """How ``PolicyStep.hidden`` is pooled over positions."""

    def step(self, image: np.ndarray, instruction: str) -> PolicyStep:
        """Act on the raw agentview render (``obs["agentview_image"]``: H×W×3 uint8, upside down as
        robosuite renders it); the policy applies OpenVLA's LIBERO preprocessing itself."""
        ...

    def describe(self) -> JsonObject:
        """JSON-ready metadata: model id, config, dims, pooling, dtype, device."""
        ...


@runtime_checkable
class BatchObserver(Protocol):
    """A policy that can also take its steps on many images at once, after the fact: the preprocessing of
    one raw render, then :meth:`steps` on the preprocessed images (what the scripted expert's collections use,
    whose actions do not depend on the model: ``vlaprobe.rollout.DeferredObserver``)."""

    def model_image(self, image: np.ndarray) -> np.ndarray:
        """The raw agentview render → the image the model sees."""
        ...

    def steps(self, model_images: np.ndarray, instruction: str) -> list[PolicyStep]:
        """One :class:`PolicyStep` per preprocessed image, as ``step`` would give it (up to rounding)."""
        ...
