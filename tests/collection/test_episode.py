"""The episode schema: what the worker writes is what ``store.episode(key)`` gives back, typed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from tests.collection.fakes import make_fake_worker
from tests.collection.test_collect import config

from vlaprobe.collection.collect import collect
from vlaprobe.collection.episode import EpisodeAttrs, EpisodeSteps
from vlaprobe.collection.store import ActivationStore
from vlaprobe.rollout import StepRecord


def test_a_stored_episode_reads_back_as_its_schema(tmp_path: Path) -> None:
    out = tmp_path / "store"
    collect(config(out, keep_failed=True, post_success_steps=2), make_fake_worker)
    store = ActivationStore.open(out)
    info = next(e for e in store.episodes() if e.success)
    ep = store.episode(info.key)
    assert ep.info == info
    attrs = ep.attributes
    assert isinstance(attrs, EpisodeAttrs) and attrs.goal is not None and attrs.scene is not None
    written = json.loads(json.dumps(attrs.to_json()))  # as stored: tuples are JSON lists
    assert written == {k: v for k, v in ep.attrs.items() if k in written} and {"goal", "scene"} <= set(
        written
    )
    assert EpisodeAttrs.from_json(attrs.to_json()) == attrs
    steps = ep.steps()
    assert isinstance(steps, EpisodeSteps) and steps.length == info.length == len(steps.world)
    arrays = steps.arrays()
    assert sorted(arrays) == sorted(ep)
    for name, a in arrays.items():
        np.testing.assert_array_equal(a, ep[name], err_msg=name)
    assert EpisodeSteps.from_arrays(arrays).arrays().keys() == arrays.keys()


def test_a_stored_episode_yields_the_loops_records(tmp_path: Path) -> None:
    out = tmp_path / "store"
    collect(config(out, keep_failed=True, post_success_steps=2), make_fake_worker)
    store = ActivationStore.open(out)
    info = next(e for e in store.episodes() if e.success)
    ep = store.episode(info.key)
    records = list(ep.records())
    assert all(isinstance(r, StepRecord) for r in records) and len(records) == info.length
    assert [r.t for r in records] == list(range(info.length)) and [r.terminal for r in records][-2:] == [
        False,
        True,
    ]
    assert info.success_step is not None and [r.success for r in records].index(True) == info.success_step
    r = records[1]
    np.testing.assert_array_equal(r.hidden, ep["hidden"][:, 1].astype(np.float32))
    np.testing.assert_array_equal(r.object_atoms, ep["object_atoms"][1])
    np.testing.assert_array_equal(r.model_image, ep["image"][1])
    assert r.step == int(ep["step"][1]) and r.raw_image is None and r.world is None and r.timings is None
    assert not any(r.perturbed for r in records)  # collected without --perturb


def test_a_scene_stored_before_issue_35_reads_back() -> None:
    """Stores written before the suites carry no receptacles, doors, close or off rules, and articulations without
    ``strict``: they read back with the defaults, the same atoms and the same rules."""
    import dataclasses

    from vlaprobe.collection.episode import stored_scene
    from vlaprobe.envs.spatial_scene import SPATIAL_GOAL, SPATIAL_SCENE
    from vlaprobe.symbols import build_vocabulary

    old = json.loads(json.dumps(dataclasses.asdict(SPATIAL_SCENE)))
    for key in ("receptacles", "doors", "door_articulation", "close_articulation", "off_articulation"):
        del old[key]
    for key in ("container_articulation", "on_off_articulation"):
        for rule in old[key]:
            del rule["strict"]
    scene, goal = stored_scene({"scene": old, "goal": dataclasses.asdict(SPATIAL_GOAL)})
    assert scene == dataclasses.replace(SPATIAL_SCENE, close_articulation=(), off_articulation=())
    old_vocab, vocab = build_vocabulary(scene), build_vocabulary(SPATIAL_SCENE)
    assert (old_vocab.object_atoms, old_vocab.action_atoms) == (vocab.object_atoms, vocab.action_atoms)
    assert goal == SPATIAL_GOAL
