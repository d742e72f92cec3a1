"""DAgger on real LIBERO: with beta 1 the dagger driver is the expert driver, label for label; with beta 0 the
model acts and the expert still labels every row, re-planning from where the model took the arm."""

from __future__ import annotations

import numpy as np
import pytest
from tests.collection.fakes import FakePolicy

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.envs.libero import LiberoTaskEnv
from vlaprobe.rollout import StepRecord, make_driver, run_episode

pytestmark = pytest.mark.libero


def episode(env: LiberoTaskEnv, driver: str, beta: float, max_steps: int) -> list[StepRecord]:
    policy = FakePolicy(PolicyConfig())
    chosen = make_driver(driver, env, policy, 5, beta)  # type: ignore[arg-type]
    return list(run_episode(env, policy, chosen, init=1, max_steps=max_steps))


def test_dagger_with_beta_1_is_the_expert_and_with_beta_0_labels_the_models_states() -> None:
    with LiberoTaskEnv(0, EnvConfig(image_size=64)) as env:
        expert = episode(env, "expert", 0.0, 300)
        dagger = episode(env, "dagger", 1.0, 300)
        model = episode(env, "dagger", 0.0, 40)
    assert expert[-1].success and len(dagger) == len(expert) and dagger[-1].success
    assert all(r.expert_action is None for r in expert)
    for e, d in zip(expert, dagger, strict=True):
        np.testing.assert_array_equal(d.action, e.action)
        np.testing.assert_array_equal(d.expert_action, e.action)  # the label is what the expert executed
    labels = np.stack([r.expert_action for r in model])
    executed = np.stack([r.action for r in model])
    np.testing.assert_array_equal(executed, np.stack([r.predicted_action for r in model]))
    np.testing.assert_array_equal(labels[0], expert[0].action)  # the same state at reset: the same label
    assert np.isfinite(labels).all() and not np.allclose(labels, executed)
    # The arm went where the model sent it, so the expert's later labels differ from its own trajectory's.
    assert not np.allclose(labels[10:40], np.stack([r.action for r in expert[10:40]]))
