"""The push's controller memory: a push the object resisted must not carry its integral into the next approach
(LIBERO-goal task 5, init 1: the wound-up term held the hand 3 cm short of the next start for 80 steps)."""

from __future__ import annotations

import numpy as np

from vlaprobe.experts.push import Push


def test_a_new_approach_starts_without_the_pushs_integral() -> None:
    skill = Push.__new__(Push)  # only the phase change: no simulator
    skill._integral = np.array([0.0, 0.6, 0.0])  # wound up pushing towards +y
    skill._enter("push")
    np.testing.assert_array_equal(skill._integral, [0.0, 0.6, 0.0])  # kept while pushing
    skill._enter("approach")
    np.testing.assert_array_equal(skill._integral, np.zeros(3))
