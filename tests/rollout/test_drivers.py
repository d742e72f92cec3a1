"""The DAgger driver: who acts at each step, the expert's label on every row, seeded draws."""

from __future__ import annotations

import numpy as np
import pytest
from tests.collection.fakes import FakeEnv, FakePolicy, FakeScriptedExpert, succeeds

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.base import PolicyStep
from vlaprobe.rollout import DaggerDriver, run_episode

FAIL_INIT = next(i for i in range(12) if not succeeds(0, i))
SUCCESS_INIT = next(i for i in range(12) if succeeds(0, i))


class CountingExpert:
    """An expert whose n-th action is [n, 0, ..., 0]: shows which call a label came from."""

    def __init__(self) -> None:
        self.calls = 0

    def reset(self) -> None:
        self.calls = 0

    def act(self) -> np.ndarray:
        self.calls += 1
        return np.array([self.calls, 0, 0, 0, 0, 0, 1.0])


def step(action: float) -> PolicyStep:
    return PolicyStep(
        action=np.full(7, action),
        hidden=np.zeros(1, np.float32),
        model_image=np.zeros((2, 2, 3), np.uint8),
        action_tokens=np.zeros(7, np.int64),
    )


def executed_by_expert(driver: DaggerDriver, steps: int) -> list[bool]:
    driver.reset()
    out = []
    for _ in range(steps):
        action = driver.act(None, step(-5.0))  # type: ignore[arg-type]
        label = driver.expert_label()
        assert label is not None and label[0] == driver.expert.calls  # asked every step, whoever acts
        out.append(bool(action[0] != -5.0))
    return out


def test_beta_sets_who_acts_and_the_expert_always_labels() -> None:
    assert executed_by_expert(DaggerDriver(CountingExpert(), 3, beta=0.0), 50) == [False] * 50
    assert executed_by_expert(DaggerDriver(CountingExpert(), 3, beta=1.0), 50) == [True] * 50
    half = executed_by_expert(DaggerDriver(CountingExpert(), 3, beta=0.5), 400)
    assert 150 < sum(half) < 250  # binomial(400, 0.5): 6 standard deviations either side
    driver = DaggerDriver(CountingExpert(), 3, beta=0.5)
    assert executed_by_expert(driver, 400) == half  # seeded
    assert executed_by_expert(driver, 400) == half  # reset restarts the draws
    assert executed_by_expert(DaggerDriver(CountingExpert(), 4, beta=0.5), 400) != half


@pytest.mark.parametrize("beta", [-0.1, 1.5, float("nan")])
def test_beta_outside_0_1_is_refused(beta: float) -> None:
    with pytest.raises(VlaprobeError, match="--dagger-beta must be between 0 and 1"):
        DaggerDriver(CountingExpert(), 0, beta)


def test_loop_records_the_expert_label_next_to_the_executed_action() -> None:
    env = FakeEnv(0, None)
    policy = FakePolicy(PolicyConfig())
    driver = DaggerDriver(FakeScriptedExpert(env), 0, beta=0.0)
    rows = list(run_episode(env, policy, driver, init=FAIL_INIT, max_steps=4))
    assert len(rows) == 4
    for r in rows:
        np.testing.assert_array_equal(r.action, r.predicted_action)  # beta 0: the model acts
        assert r.expert_action is not None and r.expert_action[6] == (1.0 if r.t > 1 else -1.0)
    env = FakeEnv(0, None)
    rows = list(
        run_episode(
            env, policy, DaggerDriver(FakeScriptedExpert(env), 0, 0.0), init=SUCCESS_INIT, max_steps=20
        )
    )
    assert rows[-1].terminal and np.isnan(rows[-1].expert_action).all() and np.isnan(rows[-1].action).all()
