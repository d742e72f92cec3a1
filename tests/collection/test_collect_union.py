"""A store of tasks with different objects: the union vocabulary, widened labels and undefined atoms.

The fake part gives task 1 one more object (a cup) than task 0; the LIBERO part (``heavy``) collects tasks 0 and 1
of LIBERO-object with the scripted expert and trains probes on the store.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from tests.collection.fakes import SCENE, FakeEnv, make_fake_worker
from tests.collection.test_collect import config

from vlaprobe.collection.collect import collect
from vlaprobe.collection.episode import stored_scene, world_states
from vlaprobe.collection.info import info
from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs.collect import InfoConfig
from vlaprobe.symbols import HEADS, Labeler, build_vocabulary

CUP_SCENE = dataclasses.replace(SCENE, pickupable=(*SCENE.pickupable, "cup"))


@pytest.fixture
def cup_in_task_1(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(FakeEnv, "SCENES", {1: CUP_SCENE})


def test_union_store_widens_labels_and_marks_the_absent_objects(
    tmp_path: Path, cup_in_task_1: None, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "store"
    collect(config(out, tasks=(0, 1), episodes_per_task=2), make_fake_worker)
    store = ActivationStore.open(out)
    capsys.readouterr()
    info(InfoConfig(path=out))
    n0, n = sum(e.task == 0 for e in store.episodes()), len(store.episodes())
    cups = len(build_vocabulary(CUP_SCENE).object_atoms) - len(build_vocabulary(SCENE).object_atoms)
    # task 0 lacks the cup's atoms: object ones, grasped(cup) and should-move-towards(cup)
    assert (
        f"undefined object {cups} atoms in {n0}; action 2 atoms in {n0} of {n} episodes"
        in capsys.readouterr().out
    )
    small, large = build_vocabulary(SCENE), build_vocabulary(CUP_SCENE)
    assert store.atom_names == {h: list(large.atoms(h)) for h in HEADS}  # the union: task 1's is a superset
    assert store.records_defined()
    cup = [a for a in store.atom_names["object"] if "cup" in a]
    assert cup and set(cup) == set(large.object_atoms) - set(small.object_atoms)
    for episode, ep in store.iter_episodes():
        keys = [episode.key]
        for head in HEADS:
            names = store.atom_names[head]
            mask, labels = store.defined(head, keys), store.labels(head, keys)
            own = (large if episode.task == 1 else small).atoms(head)
            assert mask.all(0).tolist() == [a in own for a in names]  # defined: the task's own atoms
            assert not labels[:, ~mask[0]].any()  # nothing stored where undefined
            # the stored columns of the task's atoms are its own labeller's, in its order
            labeler = Labeler(*stored_scene(ep.attrs))
            bits = np.stack([labeler(s)[HEADS.index(head)] for s in world_states(ep)])
            np.testing.assert_array_equal(labels[:, [names.index(a) for a in own]], bits)


def test_same_scenes_write_no_attribute(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "store"
    collect(config(out, tasks=(0, 2), episodes_per_task=1), make_fake_worker)
    store = ActivationStore.open(out)
    info(InfoConfig(path=out))
    assert "undefined" not in capsys.readouterr().out and store.undefined() == {
        "object": (0, 0),
        "action": (0, 0),
    }
    assert not store.records_defined() and store.atom_names["object"] == list(
        build_vocabulary(SCENE).object_atoms
    )
