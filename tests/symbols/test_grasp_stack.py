"""grasped(a) when the gripper lifts a stack: one finger on the grasped object, the other on the one on top."""

from __future__ import annotations

import numpy as np
from tests.symbols.test_detectors import IDX, finger, make_state, place, touch, truths


def stacked() -> object:
    """bowl2 rests on bowl (in contact, higher); the fingers ~4.5 mm apart, closing on the stack."""
    state = make_state(gripper_qpos=np.array([0.00225, -0.00225]))
    x, y, z = state.pos[IDX["bowl"]]
    place(state, "bowl2", (x, y, z + 0.03))
    touch(state, IDX["bowl"], IDX["bowl2"])
    return state


def test_a_finger_on_the_stacked_object_counts_for_the_one_below() -> None:
    state = stacked()
    finger(state, "bowl", 0)
    finger(state, "bowl2", 1)
    t = truths(state)
    assert "grasped(bowl)" in t and "grasped(bowl2)" not in t


def test_the_stack_rule_does_not_reach_down_nor_apart() -> None:
    state = stacked()
    finger(state, "bowl2", 0)  # a finger on the top object, the other on a third one: no grasp
    finger(state, "box", 1)
    assert not {a for a in truths(state) if a.startswith("grasped")}
    state = stacked()
    finger(state, "bowl2", 0)
    finger(state, "bowl2", 1)
    finger(state, "bowl", 0)  # both fingers on the top object: that one is grasped, as before
    t = truths(state)
    assert "grasped(bowl2)" in t and "grasped(bowl)" not in t
