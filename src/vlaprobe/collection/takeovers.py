"""The supervisor of a collected episode under ``--takeover``: the random control here, the alarm injected.

The cognition's alarm lives above collection (``vlaprobe.cognition``); a caller that has it passes a
:data:`MakeSupervisor` to the worker. The random control's takeovers need no cognition to start: each episode
gets as many takeovers as the episode of the same task and init state in the alarm run's store
(``--takeover-match``), at rows drawn from its seed within that episode's length; under ``--takeover-until
subgoal`` the cognition hands them back (the supervisor is built with these rows as its trigger).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.envs.base import TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout.takeover import RandomTakeovers, Supervisor, Takeovers

MakeSupervisor = Callable[[TaskEnv, TakeoverConfig, str, Supervisor | None], Supervisor]
"""Builds the cognition's supervisor of one episode: (simulator, settings, the observing model's id: probes
that read the hidden states must be that model's, the trigger that asks for takeovers instead of the alarm:
the random control's rows, or None)."""


def matched_counts(store: Path, suite: str, model_id: str) -> dict[tuple[int, int], tuple[int, int]]:
    """(task, init) -> (takeovers, rows) of every episode of an alarm run's store, which must be of this
    collection's suite and model (a task index of another suite names another task)."""
    opened = ActivationStore.open(store)
    meta = opened.metadata
    for what, theirs, ours in (("suite", meta.suite, suite), ("model", meta.model_id, model_id)):
        if theirs != ours:
            raise VlaprobeError(
                f"--takeover-match {store} is a store of {what} {theirs}, this collection's is {ours}; "
                "match an alarm run of the same suite and model"
            )
    out: dict[tuple[int, int], tuple[int, int]] = {}
    for info in opened.episodes():
        raw = opened.episode(info.key).attrs.get("takeovers")
        if raw is None:
            raise VlaprobeError(
                f"episode {info.key} of {store} has no takeovers; match a --takeover alarm store"
            )
        out[(info.task, info.init)] = (len(Takeovers.from_json(raw).items), info.length)
    return out


def random_supervisor(
    counts: dict[tuple[int, int], tuple[int, int]], task: int, init: int, seed: int, cfg: TakeoverConfig
) -> RandomTakeovers:
    """The random control of one episode, matched to the alarm run's episode of the same task and init."""
    if (task, init) not in counts:
        raise VlaprobeError(
            f"--takeover-match has no episode of task {task} from init state {init}; "
            "collect the same tasks and init states as the alarm run"
        )
    count, rows = counts[(task, init)]
    return RandomTakeovers(count, seed, rows, cfg.takeover_steps)
