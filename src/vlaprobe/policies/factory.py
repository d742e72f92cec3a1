"""Build a policy from its config: the one place that knows the implementations behind ``VLAPolicy``.

Every caller (the CLI, collection workers, the live server) goes through :func:`make_policy`; torch and the
models are imported only when it is called.
"""

from __future__ import annotations

from vlaprobe.configs.env import SuiteName
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.policies.base import VLAPolicy


def make_policy(cfg: PolicyConfig, suite: SuiteName | str = "libero_spatial") -> VLAPolicy:
    """The policy ``cfg`` describes, un-normalising actions with ``suite``'s statistics unless
    ``cfg.unnorm_key`` names others.

    ``cfg.model``: "tiny" for the tiny OpenVLA with random weights built deterministically from ``cfg.seed`` (no
    file needed), a shipped model's name ("tiny-libero", the trained default:
    :mod:`vlaprobe.policies.openvla.embedded`), else a checkpoint folder: an official OpenVLA one (config.json, *.safetensors shards (+ index),
    dataset_statistics.json or norm_stats in config.json, tokenizer.json) or one written by
    ``OpenVLAPolicy.save_pretrained``, or a hub id (``owner/name``, from huggingface_hub's cache). See :class:`~vlaprobe.configs.policy.PolicyConfig` for the rest.
    """
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    return OpenVLAPolicy.load(
        cfg.model,
        pooling=cfg.pooling,
        device=cfg.device,
        seed=cfg.seed,
        unnorm_key=cfg.unnorm_key,
        suite=suite,
        center_crop=cfg.center_crop,
        preprocessing=cfg.preprocessing,
    )
