"""The body grasp's side: the narrow one, unless the other (if the fingers can take it) keeps the gripper clearer
of its neighbours or the narrow one's descent was blocked."""

from __future__ import annotations

import numpy as np

from vlaprobe.experts.body_pick import X_AXIS, Y_AXIS, BodyPickPlace


def side(
    size: tuple[float, float, float], blocked: list[np.ndarray], clearance: tuple[float, float] = (1.0, 1.0)
) -> np.ndarray:
    """The side chosen for a box of ``size`` with ``blocked`` sides, the gripper swept at the X and at the Y
    side keeping ``clearance`` from every other geom."""
    skill = BodyPickPlace.__new__(BodyPickPlace)  # only the side choice: no simulator
    skill._blocked = list(blocked)
    skill._wrist_axis = lambda axis: axis  # type: ignore[method-assign]
    levels: list[np.ndarray] = []

    def sweep(lo: np.ndarray, hi: np.ndarray, at: np.ndarray):  # type: ignore[no-untyped-def]
        levels.append(at)
        return lambda grip, axis: np.full(len(at), clearance[0] if axis is X_AXIS else clearance[1])

    skill._sweep = sweep  # type: ignore[method-assign]
    skill._choose_side(np.zeros(3), np.array(size))
    assert all(at.min() < 0 < at.max() for at in levels)  # from the grasp's depth up to the approach height
    return skill._side


def test_a_blocked_side_switches_to_the_other_when_it_fits() -> None:
    assert side((0.04, 0.06, 0.1), []) is X_AXIS
    assert side((0.04, 0.06, 0.1), [X_AXIS]) is Y_AXIS
    assert side((0.04, 0.06, 0.1), [Y_AXIS], clearance=(0.0, 1.0)) is X_AXIS  # the other one was blocked


def test_a_side_wider_than_the_fingers_take_is_never_straddled() -> None:
    assert side((0.04, 0.12, 0.1), [X_AXIS]) is X_AXIS  # 12 cm across y: keep the narrow side
    assert side((0.12, 0.04, 0.1), [Y_AXIS]) is Y_AXIS
    assert side((0.04, 0.12, 0.1), [], clearance=(0.0, 1.0)) is X_AXIS


def test_the_clearer_side_wins_over_the_narrower_one() -> None:
    """An item knocked off beside the basket: the hand spans the finger axis and meets the wall at the narrow
    side; the other side is clear (clearances above 1 cm count as equally free)."""
    assert side((0.04, 0.06, 0.1), [], clearance=(0.002, 0.03)) is Y_AXIS
    assert side((0.04, 0.06, 0.1), [], clearance=(0.012, 0.03)) is X_AXIS  # both free: the narrow side
