"""Takeovers on hand-made pieces: the expert acts when asked, the random rows, the stored attribute."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from vlaprobe.collection.episode import EpisodeAttrs
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout import EpisodeControl
from vlaprobe.rollout.takeover import RandomTakeovers, Takeover, TakeoverDriver, Takeovers, random_rows


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
    assert driver.log.items == [Takeover(2, "stall: test", 3, "steps")] and driver.log.expert_steps == 3


def _run(
    driver: TakeoverDriver, control: EpisodeControl, rows: int, asks: dict[int, tuple[str, str]]
) -> list[float]:
    """Who acted at each row; ``asks``: row -> ("take", reason) or ("back", reason), asked before that row."""
    driver.reset()
    acted = []
    for row in range(rows):
        if row in asks:
            kind, reason = asks[row]
            control.take_over(reason) if kind == "take" else control.hand_back(reason)
        acted.append(float(driver.act(None, None)[0]))  # type: ignore[arg-type]
    return acted


def test_until_subgoal_the_expert_hands_back_when_asked() -> None:
    control = EpisodeControl()
    driver = TakeoverDriver(_Const(0.0), _Const(1.0), control, steps=10, mode="alarm", until="subgoal")
    acted = _run(driver, control, 9, {1: ("take", "stall: x"), 4: ("back", "subgoal: grasped(a)")})
    assert acted == [0, 1, 1, 1, 0, 0, 0, 0, 0]
    assert driver.log.items == [Takeover(1, "stall: x", 3, "subgoal: grasped(a)")]
    assert driver.log.until == "subgoal"


def test_until_subgoal_the_cap_ends_a_takeover_nobody_hands_back() -> None:
    control = EpisodeControl()
    driver = TakeoverDriver(_Const(0.0), _Const(1.0), control, steps=3, mode="random", until="subgoal")
    acted = _run(driver, control, 7, {1: ("take", "random"), 6: ("back", "late")})
    assert acted == [0, 1, 1, 1, 0, 0, 0]
    assert driver.log.items == [Takeover(1, "random", 3, "cap")]  # a hand-back after the cap changes nothing


def test_until_steps_ignores_a_hand_back() -> None:
    control = EpisodeControl()
    driver = TakeoverDriver(_Const(0.0), _Const(1.0), control, steps=3, mode="alarm", until="steps")
    acted = _run(driver, control, 6, {1: ("take", "a"), 2: ("back", "subgoal: x")})
    assert acted == [0, 1, 1, 1, 0, 0] and driver.log.items[0].ended == "steps"


def test_an_unknown_hand_back_rule_is_refused() -> None:
    with pytest.raises(VlaprobeError, match="--takeover-until must be subgoal or steps"):
        TakeoverDriver(_Const(0.0), _Const(1.0), EpisodeControl(), steps=3, mode="alarm", until="never")


def _record(t: int, under: Takeover | None = None, terminal: bool = False) -> Any:
    return SimpleNamespace(t=t, takeover=under, terminal=terminal)


def test_a_random_row_under_the_expert_waits_for_the_hand_back() -> None:
    control = RandomTakeovers(2, 3, 100, 1)
    control.rows = (5, 7)  # the second falls inside the first takeover
    under = Takeover(6, "random")
    asked = [t for t in range(20) if control.observe(_record(t, under if 6 <= t < 12 else None))]
    assert asked == [5, 12] and control.hand_back() is None
    late = RandomTakeovers(1, 3, 100, 1)
    late.rows = (4,)
    records = [_record(t, under if t == 4 else None, terminal=t == 5) for t in range(6)]
    assert not [r.t for r in records if late.observe(r)]  # put off to the last row, which has no next action


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
    log = Takeovers(
        "random", [Takeover(4, "random", 60, "subgoal: grasped(a)"), Takeover(90, "random", 12)], "subgoal"
    )
    attrs = EpisodeAttrs(instruction="x", scene=None, goal=None, takeovers=log)
    stored = attrs.to_json()
    assert stored["takeovers"]["version"] == 2 and stored["takeovers"]["expert_steps"] == 72
    assert EpisodeAttrs.from_json(stored).takeovers == log
    assert EpisodeAttrs.from_json({"instruction": "x"}).takeovers is None  # an older store
    v1 = {
        "version": 1,
        "mode": "alarm",
        "items": [{"row": 3, "reason": "stall: x", "steps": 60}],
        "expert_steps": 60,
    }
    old = EpisodeAttrs.from_json({"instruction": "x", "takeovers": v1}).takeovers  # fixed-length takeovers
    assert old == Takeovers("alarm", [Takeover(3, "stall: x", 60, "")], "steps")
    with pytest.raises(VlaprobeError, match="version 3"):
        EpisodeAttrs.from_json({"instruction": "x", "takeovers": {**stored["takeovers"], "version": 3}})
