"""Takeovers on hand-made pieces: the expert acts when asked, the random rows, the stored attribute."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from vlaprobe.collection.episode import EpisodeAttrs
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout import EpisodeControl
from vlaprobe.rollout.takeover import Takeover, TakeoverDriver, Takeovers, random_rows


class _Const:
    def __init__(self, value: float) -> None:
        self.value = value

    def reset(self) -> None:
        pass

    def act(self, obs: Any, prediction: Any) -> np.ndarray:
        return np.full(7, self.value)

    def expert_label(self) -> np.ndarray | None:
        return None


def test_the_expert_acts_for_its_steps_once_asked_then_hands_back() -> None:
    control = EpisodeControl()
    driver = TakeoverDriver(_Const(0.0), _Const(1.0), control, steps=3, mode="alarm")
    driver.reset()
    acted = []
    for row in range(8):
        if row == 2:
            control.take_over("stall: test")
        acted.append(float(driver.act(None, None)[0]))  # type: ignore[arg-type]
    assert acted == [0, 0, 1, 1, 1, 0, 0, 0]
    assert driver.log.items == [Takeover(2, "stall: test", 3)] and driver.log.expert_steps == 3


def test_a_request_while_the_expert_acts_is_dropped() -> None:
    control = EpisodeControl()
    driver = TakeoverDriver(_Const(0.0), _Const(1.0), control, steps=3, mode="alarm")
    driver.reset()
    control.take_over("a")
    driver.act(None, None)  # type: ignore[arg-type]
    control.take_over("b")
    for _ in range(5):
        driver.act(None, None)  # type: ignore[arg-type]
    assert [t.reason for t in driver.log.items] == ["a"]


@pytest.mark.parametrize(("count", "horizon", "steps"), [(0, 50, 10), (1, 50, 10), (3, 120, 30), (4, 30, 20)])
def test_random_rows_have_the_count_and_fit_the_horizon(count: int, horizon: int, steps: int) -> None:
    rows = random_rows(count, 7, horizon, steps)
    assert len(rows) == count and len(set(rows)) == count
    assert all(0 <= r < horizon - 1 for r in rows) and list(rows) == sorted(rows)
    if count * steps <= horizon - 1 and count > 1:
        assert min(np.diff(rows)) >= steps
    assert rows == random_rows(count, 7, horizon, steps)


def test_random_rows_vary_with_the_seed() -> None:
    assert len({random_rows(2, s, 200, 40) for s in range(10)}) > 1


def test_takeovers_round_trip_in_the_episode_attributes() -> None:
    log = Takeovers("random", [Takeover(4, "random", 60), Takeover(90, "random", 12)])
    attrs = EpisodeAttrs(instruction="x", scene=None, goal=None, takeovers=log)
    stored = attrs.to_json()
    assert stored["takeovers"]["version"] == 1 and stored["takeovers"]["expert_steps"] == 72
    assert EpisodeAttrs.from_json(stored).takeovers == log
    assert EpisodeAttrs.from_json({"instruction": "x"}).takeovers is None  # an older store
    with pytest.raises(VlaprobeError, match="version 2"):
        EpisodeAttrs.from_json({"instruction": "x", "takeovers": {**stored["takeovers"], "version": 2}})
