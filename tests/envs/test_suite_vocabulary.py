"""The suite vocabulary: the union of the tasks' scenes, with a mask of the atoms each task defines."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from vlaprobe.configs.env import SUITES
from vlaprobe.envs.spatial_scene import SPATIAL_SCENE
from vlaprobe.envs.suite_vocabulary import (
    defined_mask,
    suite_vocabulary,
    tasks_defined,
    union_scene,
    vocabulary_of,
)
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Articulation, build_vocabulary

REAL_ASSETS = os.environ.get("VLAPROBE_LIBERO_ASSETS")
needs_assets = pytest.mark.skipif(not REAL_ASSETS, reason="needs LIBERO's assets (VLAPROBE_LIBERO_ASSETS)")

# A second task: the ramekin and second bowl gone, a basket (with its contain region) in their place.
BASKET_TASK = dataclasses.replace(
    SPATIAL_SCENE,
    pickupable=("akita_black_bowl_1", "cookies_1", "plate_1", "basket_1"),
    receptacles=("basket_1_contain_region",),
    region_parent={**SPATIAL_SCENE.region_parent, "basket_1_contain_region": "basket_1"},
)


def test_the_union_of_one_scene_is_itself() -> None:
    assert union_scene([SPATIAL_SCENE]) == SPATIAL_SCENE
    vocab = vocabulary_of("libero_spatial", [SPATIAL_SCENE] * 3)
    assert vocab.vocabulary == build_vocabulary(SPATIAL_SCENE)
    assert (
        vocab.object_defined.shape == (3, 224) and vocab.object_defined.all() and vocab.action_defined.all()
    )


def test_atoms_over_absent_objects_are_undefined_not_false() -> None:
    vocab = vocabulary_of("mixed", [SPATIAL_SCENE, BASKET_TASK])
    union = vocab.vocabulary.scene
    assert union.pickupable == (*SPATIAL_SCENE.pickupable, "basket_1")
    assert union.receptacles == ("basket_1_contain_region",)
    atoms = vocab.vocabulary.object_atoms
    index = {a: i for i, a in enumerate(atoms)}
    spatial_row, basket_row = vocab.defined("object")
    for name, in_spatial, in_basket in [
        ("on(akita_black_bowl_1,plate_1)", True, True),
        ("on(akita_black_bowl_2,plate_1)", True, False),
        ("inside(cookies_1,basket_1_contain_region)", False, True),
        ("behind(basket_1,glazed_rim_porcelain_ramekin_1)", False, False),
        ("open(wooden_cabinet_1_top_region)", True, True),
    ]:
        assert (spatial_row[index[name]], basket_row[index[name]]) == (in_spatial, in_basket), name
    # Each task's defined atoms are exactly its own vocabulary.
    for scene, row in zip(vocab.scenes, vocab.object_defined, strict=True):
        assert {a for a, d in zip(atoms, row, strict=True) if d} == set(build_vocabulary(scene).object_atoms)
    grasped = vocab.vocabulary.action_atoms.index("grasped(basket_1)")
    assert vocab.defined("action")[:, grasped].tolist() == [False, True]
    assert defined_mask(["on(a,b)"], SPATIAL_SCENE).tolist() == [False]


def test_one_name_with_two_joint_rules_is_refused() -> None:
    other = dataclasses.replace(SPATIAL_SCENE, on_off_articulation=(Articulation(0.3, below=False),))
    with pytest.raises(VlaprobeError, match="flat_stove_1 has different joint rules in two tasks"):
        union_scene([SPATIAL_SCENE, other])


@needs_assets
@pytest.mark.parametrize("suite", SUITES)
def test_each_task_defines_exactly_its_own_atoms(suite: str) -> None:
    vocab = suite_vocabulary(suite)  # type: ignore[arg-type]
    for head in ("object", "action"):
        atoms = np.array(vocab.vocabulary.atoms(head))
        for scene, row in zip(vocab.scenes, vocab.defined(head), strict=True):
            assert set(atoms[row]) == set(build_vocabulary(scene).atoms(head))
    if suite == "libero_spatial":
        assert vocab.vocabulary == build_vocabulary(SPATIAL_SCENE)


@needs_assets
def test_tasks_defined_reads_each_tasks_scene() -> None:
    """cream_cheese_1 is on the table of LIBERO-object's task 1, not of task 5; the basket is in both."""
    atoms = ["grasped(cream_cheese_1)", "inside(cream_cheese_1,basket_1)", "grasped(basket_1)"]
    mask = tasks_defined("libero_object", atoms, [1, 5, 1])
    np.testing.assert_array_equal(mask, [[True, True, True], [False, False, True], [True, True, True]])
    assert tasks_defined("libero_goal", atoms, []).shape == (0, 3)
