"""Real expert episodes of all 10 LIBERO-spatial tasks: the shipped rules hold on ground truth, the subgoals
go 1 -> 2 -> 3 -> 4 and the goal is reached on the step LIBERO's own success check first holds.

One env per task, init state 0, no rendering; the expert goes on for POST steps after success (it lets go
and lifts the arm), as collection's post_success_steps does.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from vlaprobe.cognition import Cognition, CognitionConfig
from vlaprobe.cognition.prolog import prolog_violations
from vlaprobe.configs.monitor import DEFAULT_DEBOUNCE
from vlaprobe.symbols import Goal

pytestmark = [pytest.mark.libero, pytest.mark.timeout(900)]
POST, MAX_STEPS = 15, 300


@dataclass
class Episode:
    task: int
    goal: Goal
    object_atoms: tuple[str, ...]
    action_atoms: tuple[str, ...]
    obj: np.ndarray
    act: np.ndarray
    success_step: int | None


def expert_rows(
    env: Any, expert: Any, post: int, max_steps: int, each_row: Callable[[], object] | None = None
) -> tuple[list, int | None, bool]:
    """The labeler's (object, action) rows of an expert episode from init 0, going on ``post`` steps after LIBERO's
    success (at most ``max_steps``), the first row of success (None: none), and LIBERO's goal check at the end.
    ``each_row`` is called on the live simulator after every row is labelled (to read LIBERO's own predicates)."""
    env.reset(0)
    expert.reset()
    rows, success_step, success = [env.labeler(env.world_state())], None, False
    if each_row is not None:
        each_row()
    while len(rows) <= max_steps and (success_step is None or len(rows) <= success_step + post):
        obs = env.step(expert.act())
        rows.append(env.labeler(env.world_state()))
        if each_row is not None:
            each_row()
        success = obs.success
        if success and success_step is None:
            success_step = len(rows) - 1
    return rows, success_step, success


@pytest.fixture(scope="module")
def episodes() -> list[Episode]:
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.libero import LiberoTaskEnv
    from vlaprobe.experts import ScriptedExpert

    out = []
    for task in range(10):
        with LiberoTaskEnv(task, EnvConfig(render=False)) as env:
            rows, success_step, _ = expert_rows(env, ScriptedExpert(env, seed=0), POST, MAX_STEPS)
            vocab = env.labeler.vocabulary
            out.append(
                Episode(
                    task,
                    env.goal,
                    vocab.object_atoms,
                    vocab.action_atoms,
                    np.array([o for o, _ in rows]),
                    np.array([a for _, a in rows]),
                    success_step,
                )
            )
    return out


def run(ep: Episode, debounce: int) -> list:
    cog = Cognition(ep.object_atoms, ep.action_atoms, ep.goal, CognitionConfig(debounce=debounce))
    return [cog.step(o, a) for o, a in zip(ep.obj, ep.act, strict=True)]


@pytest.mark.parametrize("debounce", [1, DEFAULT_DEBOUNCE])
def test_no_shipped_rule_fires_on_ground_truth(episodes: list[Episode], debounce: int) -> None:
    fired = {(ep.task, s.t, v.message) for ep in episodes for s in run(ep, debounce) for v in s.violations}
    assert not fired, sorted(fired)[:5]


def test_subgoals_go_in_order_and_the_goal_is_reached_with_libero_success(episodes: list[Episode]) -> None:
    for ep in episodes:
        assert ep.success_step is not None, f"the expert failed task {ep.task}"
        steps = run(ep, debounce=1)
        done = [int(e.message.split()[1]) for s in steps for e in s.events if e.kind == "subgoal_done"]
        assert done == [1, 2, 3, 4], (ep.task, done)
        reached = next(s.t for s in steps if s.goal_reached)
        assert abs(reached - ep.success_step) <= 1, (ep.task, reached, ep.success_step)
        assert steps[-1].goal_reached and steps[-1].progress == 1.0
        assert not [e for s in steps for e in s.events if e.kind in ("regression", "dropped")], ep.task


@pytest.mark.skipif(shutil.which("swipl") is None, reason="SWI-Prolog (swipl) is not installed")
def test_prolog_rules_equal_clingo_on_recorded_episodes(episodes: list[Episode]) -> None:
    rng = np.random.default_rng(0)
    flagged = 0
    for ep in episodes[:4]:
        cog = Cognition(ep.object_atoms, ep.action_atoms, ep.goal, CognitionConfig(debounce=1))
        for noise in (0.0, 0.01):  # the truth, and probe-like errors on it
            cog.reset()
            asp, facts = [], []
            for o, a in zip(ep.obj, ep.act, strict=True):
                o = o ^ (rng.random(o.shape) < noise)
                a = a ^ (rng.random(a.shape) < noise)
                asp.append({(v.rule, frozenset(v.atoms)) for v in cog.step(o, a).violations})
                facts.append(cog.rules.facts())
            assert asp == prolog_violations(facts, cog.rules.type_facts), ep.task
            flagged += sum(map(len, asp))
    assert flagged > 100
