"""The one step loop on the fake simulator and model: rows, post-success rows, stop, pause and drop."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from tests.collection.fakes import FakeEnv, FakeExpert, FakePolicy, succeeds, success_step

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout import EpisodeControl, PolicyDriver, StepRecord, run_episode


def episode(init: int, **kwargs: object) -> list[StepRecord]:
    env = FakeEnv(0, None)
    kwargs = {"max_steps": 6, **kwargs}
    return list(run_episode(env, FakePolicy(PolicyConfig()), FakeExpert(env, 0), init=init, **kwargs))


SUCCESS_INIT = next(i for i in range(12) if succeeds(0, i))
FAIL_INIT = next(i for i in range(12) if not succeeds(0, i))


def test_rows_end_on_success_and_failed_episodes_drop_the_last_observation() -> None:
    rows = episode(SUCCESS_INIT)
    s = success_step(0, SUCCESS_INIT)
    assert [r.t for r in rows] == [r.step for r in rows] == list(range(s + 1))
    assert [r.success for r in rows] == [False] * s + [True]
    assert [r.terminal for r in rows] == [False] * s + [True]
    assert np.isnan(rows[-1].action).all() and not np.isnan(rows[0].action).any()
    failed = episode(FAIL_INIT)
    assert len(failed) == 6 and not any(r.terminal or r.success for r in failed)
    r = rows[0]
    assert r.hidden.shape == (4, 8) and r.model_image.shape == r.raw_image.shape
    assert r.object_atoms.dtype == bool and r.world.pos.shape == (3, 3)
    t = r.timings
    assert t.total_ms == pytest.approx(t.env_ms + t.label_ms + t.model_ms + t.driver_ms) and t.model_ms >= 0


def test_post_success_steps_keep_recording_until_the_budget() -> None:
    s = success_step(0, SUCCESS_INIT)
    rows = episode(SUCCESS_INIT, post_success_steps=2, max_steps=20)
    assert len(rows) == s + 3 and rows[-1].terminal and [r.terminal for r in rows].count(True) == 1
    assert not np.isnan(rows[s].action).any()  # the success row's action is executed now
    capped = episode(SUCCESS_INIT, post_success_steps=50, max_steps=6)
    assert len(capped) == 7 and capped[-1].terminal and np.isnan(capped[-1].action).all()
    with pytest.raises(VlaprobeError, match="post-success-steps"):
        episode(SUCCESS_INIT, post_success_steps=-1)


def test_policy_driver_executes_the_models_action() -> None:
    env = FakeEnv(0, None)
    rows = list(run_episode(env, FakePolicy(PolicyConfig()), PolicyDriver(), init=FAIL_INIT, max_steps=3))
    for r in rows:
        np.testing.assert_array_equal(r.action, r.predicted_action)


def test_drop_forces_the_gripper_open_for_that_many_steps() -> None:
    control = EpisodeControl()
    env = FakeEnv(0, None)
    rows = []
    for r in run_episode(
        env, FakePolicy(PolicyConfig()), FakeExpert(env, 0), init=FAIL_INIT, max_steps=6, control=control
    ):
        rows.append(r)
        if r.t == 1:
            control.drop(2)
    assert [r.perturbed for r in rows] == [False, False, True, True, False, False]
    assert [r.action[6] for r in rows] == [-1.0, -1.0, -1.0, -1.0, 1.0, 1.0]  # the expert closes from t = 2


def test_stop_ends_and_pause_blocks_until_resumed() -> None:
    control = EpisodeControl()
    env = FakeEnv(0, None)
    loop = run_episode(
        env, FakePolicy(PolicyConfig()), FakeExpert(env, 0), init=FAIL_INIT, max_steps=6, control=control
    )
    next(loop)
    control.pause()
    assert control.paused
    got: list[StepRecord] = []
    thread = threading.Thread(target=lambda: got.append(next(loop)))
    thread.start()
    time.sleep(0.2)
    assert not got and thread.is_alive()  # blocked before the simulator step
    control.resume()
    thread.join(5)
    assert [r.t for r in got] == [1]
    control.stop()
    assert list(loop) == [] and control.stopped and not control.paused
