"""Policies that act in LIBERO: VLA models exposing their hidden states (the scripted expert is in
``vlaprobe.envs.libero_expert``, next to the env it reads).

:func:`make_policy` (from a :class:`~vlaprobe.configs.policy.PolicyConfig`) and :func:`load_policy` (the same
with keyword arguments) import torch only when called, so importing this package stays cheap.
"""

from vlaprobe.configs.policy import POOLINGS, Pooling
from vlaprobe.policies.base import PolicyStep, VLAPolicy
from vlaprobe.policies.factory import load_policy, make_policy

__all__ = ["POOLINGS", "PolicyStep", "Pooling", "VLAPolicy", "load_policy", "make_policy"]
