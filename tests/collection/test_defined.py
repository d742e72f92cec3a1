"""The per-episode ``atoms_defined`` attribute: written by the real writer, read back as a row mask."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tests.collection.test_store import ATOMS, make_episode, make_meta, write

from vlaprobe.collection.defined import ATTR, TaskColumns, defined_attrs
from vlaprobe.collection.store import ActivationStore
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.errors import VlaprobeError


def test_store_without_attribute_reads_all_defined(tmp_path: Path) -> None:
    write(tmp_path / "s", [(0, 0, 3), (1, 0, 2)])
    store = ActivationStore.open(tmp_path / "s")
    mask = store.defined("object")
    assert mask.shape == (5, len(ATOMS["object"])) and mask.all()


def test_mask_follows_each_episode(tmp_path: Path) -> None:
    gone = ATOMS["object"][1]
    with StoreWriter.open(tmp_path / "s", make_meta()) as w:
        info, arrays = make_episode(0, 0, 3)
        w.write_episode(info, arrays, defined_attrs(ATOMS, {"object": [gone]}))
        info, arrays = make_episode(1, 0, 2)
        w.write_episode(info, arrays)
    store = ActivationStore.open(tmp_path / "s")
    mask = store.defined("object")
    expected = np.ones((5, len(ATOMS["object"])), dtype=bool)
    expected[:3, 1] = False
    np.testing.assert_array_equal(mask, expected)
    assert store.defined("action").all()
    np.testing.assert_array_equal(store.defined("object", ["t01_i00_a00"]), expected[3:])


def test_unknown_atom_and_version_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="not in the store's vocabulary"):
        defined_attrs(ATOMS, {"object": ["nope(x)"]})
    with StoreWriter.open(tmp_path / "s", make_meta()) as w:
        info, arrays = make_episode(0, 0, 2)
        w.write_episode(info, arrays, {ATTR: {"version": 99, "undefined": {}}})
    with pytest.raises(VlaprobeError, match="version 99"):
        ActivationStore.open(tmp_path / "s").defined("object")


def test_records_defined_says_whether_the_store_has_the_attribute(tmp_path: Path) -> None:
    write(tmp_path / "old", [(0, 0, 2)])
    assert not ActivationStore.open(tmp_path / "old").records_defined()
    with StoreWriter.open(tmp_path / "new", make_meta()) as w:
        info, arrays = make_episode(0, 0, 2)
        w.write_episode(info, arrays, defined_attrs(ATOMS, {}))
    assert ActivationStore.open(tmp_path / "new").records_defined()


def test_task_columns_widen_and_fold_in_the_labelers_undefined_atoms() -> None:
    store = {"object": ["a", "b", "c"], "action": ["g(x)", "t(x)"]}
    cols = TaskColumns.of(store, {"object": ["c", "a"], "action": ["g(x)", "t(x)"]}, {"action": ["t(x)"]})
    assert cols.undefined == {"object": ["b"], "action": ["t(x)"]}
    wide = cols.widen("object", np.array([[True, False], [False, True]]))
    assert wide.tolist() == [[False, False, True], [True, False, False]]
    same = np.array([[True, False]])
    assert cols.widen("action", same) is same  # the store's columns: the array itself
    attrs = cols.attrs(store)
    assert attrs[ATTR]["undefined"] == {"object": ["b"], "action": ["t(x)"]}
    assert TaskColumns.of(store, store).attrs(store) == {}  # all defined: no attribute
    with pytest.raises(VlaprobeError, match="not in the store's vocabulary"):
        TaskColumns.of(store, {"object": ["z"], "action": []})
