"""A takeover until the subgoal on real LIBERO through the one step loop and episode runner: random actions
stall, the cognition's alarm (on the true atoms) hands the arm to the scripted expert, which hands back once
the subgoal current at its start is done, well before its cap."""

from __future__ import annotations

import pytest
from tests.collection.fakes import FakePolicy

from vlaprobe.cognition.alarm import CognitionSupervisor
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.rollout import EnvCache, EpisodeControl, EpisodeRunner
from vlaprobe.rollout.takeover import TakeoverDriver

pytestmark = pytest.mark.libero
CAP = 100


def test_the_expert_hands_back_once_its_subgoal_is_done() -> None:
    cfg = TakeoverConfig(takeover="alarm", takeover_stall=5, takeover_steps=CAP, takeover_most=1)
    with LiberoTaskEnv(0, EnvConfig(image_size=64)) as env:
        runner = EpisodeRunner(FakePolicy(PolicyConfig()), EnvCache(lambda task: env))
        control, watch = EpisodeControl(), CognitionSupervisor(env, cfg, "fake")
        records = []
        for r in runner.run(
            env,
            "policy",
            init=0,
            seed=5,
            max_steps=130,
            control=control,
            takeover="alarm",
            takeover_steps=CAP,
            takeover_until=cfg.takeover_until,
        ):
            records.append(r)
            if reason := watch.observe(r):
                control.take_over(reason)
            if back := watch.hand_back():
                control.hand_back(back)
        driver = runner.driver
        assert isinstance(driver, TakeoverDriver) and driver.log.until == "subgoal"
        (taken,) = driver.log.items
        assert taken.reason.startswith("stall: ") and taken.row == 6
        assert taken.ended == f"subgoal: should-move-towards({env.goal.pick})" and taken.steps < CAP, taken
        under = [r.t for r in records if r.takeover is not None]
        assert under == list(range(taken.row, taken.row + taken.steps))
        assert records[taken.row + taken.steps].takeover is None  # the policy acts again
