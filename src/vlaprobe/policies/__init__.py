"""Policies that act in LIBERO: VLA models exposing their hidden states (the scripted expert is in
``vlaprobe.experts``, next to the env it reads).

:func:`make_policy` (from a :class:`~vlaprobe.configs.policy.PolicyConfig`, the one description of a policy:
``make_policy(PolicyConfig("tiny", device="cpu"))``) imports torch only when called, so importing this
package stays cheap.
"""

from vlaprobe.configs.policy import POOLINGS, Pooling
from vlaprobe.policies.base import PolicyStep, VLAPolicy
from vlaprobe.policies.factory import make_policy

__all__ = ["POOLINGS", "PolicyStep", "Pooling", "VLAPolicy", "make_policy"]
