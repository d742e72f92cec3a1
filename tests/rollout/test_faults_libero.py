"""Fault injection on real LIBERO through the one step loop and episode runner: an early release makes the
scripted expert drop the bowl while carrying it and give up; the episode fails from the marked row on."""

from __future__ import annotations

import numpy as np
import pytest
from tests.collection.fakes import FakePolicy

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.rollout import EnvCache, EpisodeRunner
from vlaprobe.rollout.faults import FaultSpec, FaultyExpert
from vlaprobe.symbols.vocabulary import atom

pytestmark = pytest.mark.libero


def test_release_fault_drops_the_bowl_and_the_episode_fails() -> None:
    with LiberoTaskEnv(1, EnvConfig(image_size=64)) as env:
        runner = EpisodeRunner(FakePolicy(PolicyConfig()), EnvCache(lambda task: env))
        grasp_col = env.labeler.vocabulary.action_atoms.index(atom("grasped", env.goal.pick))
        records = list(
            runner.run(env, "expert", init=0, seed=5, max_steps=100, faults=FaultSpec(release=1.0))
        )
        driver = runner.driver
        assert isinstance(driver, FaultyExpert)
        assert [m.kind for m in driver.marks] == ["release"], driver.expert.phase
        (mark,) = driver.marks
        assert mark.kind == "release" and driver.failure_step == mark.row
        grasped = np.array([bool(r.action_atoms[grasp_col]) for r in records])
        assert grasped[: mark.row + 1].any() and not grasped[mark.row + 5 :].any()  # let go, never again
        assert records[mark.row].action[6] == -1.0 and len(records) == 100  # ran out: no success
        assert not any(r.success for r in records)
