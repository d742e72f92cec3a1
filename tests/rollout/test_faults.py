"""Faults injected into the expert: the spec, the draws from the seed, and each fault on a scripted phase
sequence (the real expert on LIBERO: test_faults_libero.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tests.collection.fakes import GOAL, SCENE, FakeEnv

from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout.faults import FaultMark, FaultSpec, FaultyExpert
from vlaprobe.symbols import WorldState


class PhaseExpert:
    """Goes through a fixed list of phases, one per action; its action is 0.5 everywhere, gripper closed."""

    def __init__(self, phases: list[str]) -> None:
        self.phases, self.target = phases, GOAL.place
        self.reset()

    def reset(self) -> None:
        self.i, self.phase = 0, self.phases[0]

    def act(self) -> np.ndarray:
        self.phase = self.phases[min(self.i, len(self.phases) - 1)]
        self.i += 1
        return np.array([0.5] * 6 + [1.0])

    def retarget(self, name: str) -> None:
        self.target = name


def world() -> WorldState:
    """The bowl 0.3 m from the plate; the cabinet 5 cm tall (a low object)."""
    env = FakeEnv(0, None)
    env.reset(0)
    pos = np.array([[0.0, 0.0, 0.92], [0.3, 0.0, 0.92], [0.0, 0.3, 0.92]])
    return dataclasses.replace(env.world_state(), pos=pos, aabb_lo=pos - 0.02, aabb_hi=pos + 0.03)


def run(spec: FaultSpec, phases: list[str], seed: int = 3) -> tuple[FaultyExpert, np.ndarray]:
    driver = FaultyExpert(PhaseExpert(phases), spec, seed, SCENE, GOAL, world)
    driver.reset()
    return driver, np.stack([driver.act() for _ in phases])


def test_spec_parses_and_refuses_bad_values() -> None:
    assert FaultSpec.parse("") == FaultSpec() and not FaultSpec().any
    spec = FaultSpec.parse("noise=1.5, wrong-target=0.2")
    assert spec == FaultSpec(noise=1.5, wrong_target=0.2) and spec.text() == "noise=1.5,wrong_target=0.2"
    with pytest.raises(VlaprobeError, match="unknown fault 'shake'"):
        FaultSpec.parse("shake=0.2")
    with pytest.raises(VlaprobeError, match="release needs a probability"):
        FaultSpec.parse("release=1.5")
    with pytest.raises(VlaprobeError, match="noise needs a scale"):
        FaultSpec.parse("noise=-1")


def test_release_gives_up_while_carrying_and_marks_the_failure_step() -> None:
    phases = ["approach"] * 3 + ["carry"] * 20
    driver, actions = run(FaultSpec(release=1.0), phases)
    (mark,) = driver.marks
    assert mark.kind == "release" and driver.failure_step == mark.row
    assert 3 + 1 <= mark.row < 3 + 7  # after 1-5 carried rows
    assert np.all(actions[: mark.row] == [0.5] * 6 + [1.0])
    assert np.all(actions[mark.row :] == [0.0] * 6 + [-1.0])  # fingers open, holding still: no recovery
    again, _ = run(FaultSpec(release=1.0), phases)
    assert again.marks == driver.marks  # drawn from the seed
    assert run(FaultSpec(), phases)[0].marks == []


def test_no_recovery_gives_up_at_the_first_regrasp() -> None:
    driver, actions = run(FaultSpec(no_recovery=1.0), ["approach", "close", "regrasp", "approach", "carry"])
    assert driver.marks == [FaultMark("no_recovery", 2)] and driver.failure_step == 2
    assert actions[1, 6] == 1.0 and np.all(actions[2:, 6] == -1.0)


def test_wrong_target_retargets_to_a_low_object_and_marks_the_release() -> None:
    driver, _ = run(FaultSpec(wrong_target=1.0), ["approach", "carry", "lower", "release", "retreat"])
    assert driver.expert.target == "cabinet"  # type: ignore[attr-defined]
    assert driver.marks == [FaultMark("wrong_target", 0)] and driver.failure_step == 3


def test_noise_has_the_given_scale_and_is_seeded() -> None:
    phases = ["approach"] * 400
    _, actions = run(FaultSpec(noise=0.3), phases)
    assert abs(np.std(actions[:, :6] - 0.5) - 0.3) < 0.02 and np.all(actions[:, 6] == 1.0)
    assert np.array_equal(actions, run(FaultSpec(noise=0.3), phases)[1])
    assert not np.array_equal(actions, run(FaultSpec(noise=0.3), phases, seed=4)[1])


def test_fault_marks_round_trip_through_the_episode_attributes() -> None:
    from vlaprobe.collection.episode import EpisodeAttrs

    attrs = EpisodeAttrs("put", SCENE, GOAL, faults=[FaultMark("release", 40)], failure_step=40)
    assert EpisodeAttrs.from_json(attrs.to_json()) == attrs
    plain = EpisodeAttrs("put", SCENE, GOAL)
    assert "faults" not in plain.to_json() and EpisodeAttrs.from_json(plain.to_json()) == plain


def test_collect_refuses_faults_without_the_expert_driver() -> None:
    from vlaprobe.configs.checks import check_collect
    from vlaprobe.configs.collect import CollectConfig

    with pytest.raises(VlaprobeError, match="--expert-faults changes the scripted expert's actions"):
        check_collect(CollectConfig(driver="policy", expert_faults="noise=0.1"))
