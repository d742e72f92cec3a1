"""The body grasp's side: the narrow one, the other after a blocked descent only if the fingers can take it."""

from __future__ import annotations

import numpy as np

from vlaprobe.experts.body_pick import X_AXIS, Y_AXIS, BodyPickPlace


def side(size: tuple[float, float, float], blocked: list[np.ndarray]) -> np.ndarray:
    skill = BodyPickPlace.__new__(BodyPickPlace)  # only the side choice: no simulator
    skill._blocked = list(blocked)
    skill._wrist_axis = lambda axis: axis  # type: ignore[method-assign]
    skill._choose_side(np.zeros(3), np.array(size))
    return skill._side


def test_a_blocked_side_switches_to_the_other_when_it_fits() -> None:
    assert side((0.04, 0.06, 0.1), []) is X_AXIS
    assert side((0.04, 0.06, 0.1), [X_AXIS]) is Y_AXIS


def test_a_side_wider_than_the_fingers_take_is_never_straddled() -> None:
    assert side((0.04, 0.12, 0.1), [X_AXIS]) is X_AXIS  # 12 cm across y: keep the narrow side
    assert side((0.12, 0.04, 0.1), [Y_AXIS]) is Y_AXIS
