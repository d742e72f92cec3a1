"""The cognition's alarm: the rule on hand-made steps; alarm-driven and matched random takeovers collected on
the fake simulator through the real worker and store."""

from __future__ import annotations

import functools
from pathlib import Path

import pytest
from tests.collection.fakes import make_fake_worker

from vlaprobe.cognition.alarm import AlarmRule, CognitionSupervisor
from vlaprobe.cognition.core import CognitionStep, Violation
from vlaprobe.cognition.subgoals import Event
from vlaprobe.collection.collect import collect
from vlaprobe.collection.store import ActivationStore
from vlaprobe.collection.takeovers import matched_counts
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.rollout.takeover import Takeovers


def _step(t: int, progress: float = 0.0, violations: tuple[Violation, ...] = ()) -> CognitionStep:
    return CognitionStep(t, (), (), violations, (), progress, (), False)


def test_the_alarm_fires_on_a_stall_and_counts_from_the_hand_back() -> None:
    rule = AlarmRule(stall=5, hold=3, most=3)
    fired = [t for t in range(20) if rule.check(_step(t), acting=8 <= t < 12)]
    assert fired == [5, 16]


def test_the_alarm_names_the_rules_of_a_held_violation() -> None:
    rule = AlarmRule(stall=100, hold=3, most=1)
    v = Violation("on_and_inside", "on and inside", ("on(a,b)",), since=2)
    alarms = [rule.check(_step(t, violations=(v,) if t >= 2 else ()), acting=False) for t in range(8)]
    hits = [(t, a) for t, a in enumerate(alarms) if a is not None]
    assert [t for t, _ in hits] == [4]  # held 3 steps; at most once
    assert hits[0][1].rules == ("on_and_inside",) and hits[0][1].atoms == ("on(a,b)",)


def test_an_event_fires_at_once_and_its_reason_names_the_kind_once() -> None:
    rule = AlarmRule(stall=100, hold=3, most=2)
    event = Event("regression", 3, "regression: grasped(a) no longer done")
    alarm = rule.check(CognitionStep(3, (), (), (), (), 0.0, (event,), False), acting=False)
    assert alarm is not None and alarm.kind == "regression"
    assert alarm.text() == "regression: grasped(a) no longer done"


def _config(out: Path, **takeover: object) -> CollectConfig:
    return CollectConfig(
        out=out,
        driver="policy",
        tasks=(0, 2),
        episodes_per_task=3,
        max_tries_per_task=3,
        keep_failed=True,
        progress=False,
        intervention=TakeoverConfig(**takeover),  # type: ignore[arg-type]
        env=EnvConfig(max_steps=30, image_size=16),
    )


def _takeovers(store: Path) -> dict[tuple[int, int], Takeovers]:
    s = ActivationStore.open(store)
    return {(e.task, e.init): s.episode(e.key).attributes.takeovers for e in s.episodes()}  # type: ignore[misc]


def test_random_takeovers_match_the_alarm_runs_counts(tmp_path: Path) -> None:
    alarm = _config(tmp_path / "alarm", takeover="alarm", takeover_stall=4, takeover_steps=3)
    collect(alarm, functools.partial(make_fake_worker, make_supervisor=CognitionSupervisor))
    fired = _takeovers(alarm.out)
    assert any(t.items for t in fired.values()), "the fake episodes never stall: the test proves nothing"
    for t in fired.values():
        assert t.mode == "alarm" and all(0 <= i.steps <= 3 for i in t.items)
        assert all(i.reason.split(":")[0] in ("stall", "regression", "dropped", "violation") for i in t.items)
    rand = _config(tmp_path / "random", takeover="random", takeover_steps=3, takeover_match=alarm.out)
    collect(rand, make_fake_worker)
    matched = _takeovers(rand.out)
    assert matched.keys() == fired.keys()
    assert {k: len(t.items) for k, t in matched.items()} == {k: len(t.items) for k, t in fired.items()}
    assert all(i.reason == "random" for t in matched.values() for i in t.items)
    meta = ActivationStore.open(alarm.out).metadata
    assert matched_counts(alarm.out, meta.suite, meta.model_id).keys() == fired.keys()
    with pytest.raises(VlaprobeError, match="suite libero_spatial, this collection's is libero_goal"):
        matched_counts(alarm.out, "libero_goal", meta.model_id)
    with pytest.raises(VlaprobeError, match="store of model"):
        matched_counts(alarm.out, meta.suite, "another-model")


def test_takeover_probes_must_read_the_collecting_models_hidden_states(tmp_path: Path) -> None:
    from tests.collection.fakes import FakeEnv, fake_probed_run

    fake_probed_run(tmp_path, shuffled_control=False)
    env = FakeEnv(0, EnvConfig(max_steps=6, image_size=16))
    cfg = TakeoverConfig(takeover="alarm", takeover_probes=tmp_path / "probes")
    model = ActivationStore.open(tmp_path / "activations").metadata.model_id
    assert CognitionSupervisor(env, cfg, model).readout is not None  # type: ignore[arg-type]
    with pytest.raises(VlaprobeError, match="another-model"):
        CognitionSupervisor(env, cfg, "another-model")  # type: ignore[arg-type]
