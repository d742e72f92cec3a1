"""Environments: the LIBERO simulator behind a small interface (reset to a fixed init state, step, snapshot).

:func:`make_env` builds a task's environment from its config; :class:`~vlaprobe.envs.base.TaskEnv` is the
interface the step loop (``vlaprobe.rollout``) sees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.base import TaskEnv


def make_env(task: int | str, env_cfg: EnvConfig) -> TaskEnv:
    """The environment of one task (an index or its exact instruction) of ``env_cfg.suite``."""
    from vlaprobe.envs.libero import LiberoTaskEnv

    return LiberoTaskEnv(task, env_cfg)


__all__ = ["make_env"]
