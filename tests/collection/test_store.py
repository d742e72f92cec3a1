"""The activation store with synthetic episodes: roundtrip, layer reads, atomic publish, refusals, info."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import zarr

from vlaprobe.collection.store import (
    FORMAT_VERSION,
    ActivationStore,
    EpisodeInfo,
    episode_key,
    read_store_meta,
)
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.errors import VlaprobeError

LAYERS, HIDDEN = 5, 16
ATOMS = {"object": [f"on(o{i},o{i + 1})" for i in range(9)], "action": ["grasped(o0)", "grasped(o1)"]}


def make_meta(**changes: object) -> dict:
    meta = {
        "atom_names": ATOMS,
        "model_id": "tiny-test",
        "model": {"name": "tiny", "layers": LAYERS},
        "num_hidden_states": LAYERS,
        "hidden_size": HIDDEN,
        "pooling": "last_prompt",
        "driver": "expert",
        "suite": "libero_spatial",
        "env": {"image_size": 32},
        "seed": 0,
    }
    meta.update(changes)
    return meta


def make_episode(task: int, init: int, length: int, success: bool = True, pooling: str = "last_prompt"):
    rng = np.random.default_rng(task * 100 + init)
    info = EpisodeInfo(episode_key(task, init), task, init, 0, success, length, seed=7, driver="expert")
    shape = (LAYERS, length, 7, HIDDEN) if pooling == "action_tokens" else (LAYERS, length, HIDDEN)
    arrays = {
        "hidden": rng.standard_normal(shape).astype(np.float16),
        "object_atoms": rng.random((length, len(ATOMS["object"]))) < 0.3,
        "action_atoms": rng.random((length, len(ATOMS["action"]))) < 0.5,
        "image": rng.integers(0, 255, (length, 8, 8, 3), dtype=np.uint8),
        "action": rng.standard_normal((length, 7)).astype(np.float32),
        "step": np.arange(length, dtype=np.int32),
        "world/pos": rng.standard_normal((length, 7, 3)),
    }
    return info, arrays


def write(path: Path, episodes, meta=None) -> dict:
    written = {}
    with StoreWriter.open(path, meta or make_meta()) as w:
        for task, init, length, *rest in episodes:
            info, arrays = make_episode(task, init, length, *rest)
            w.write_episode(info, arrays, {"instruction": f"task {task}"})
            written[info.key] = arrays
    return written


def test_roundtrip_layers_labels_and_episodes(tmp_path: Path) -> None:
    path = tmp_path / "store"
    written = write(path, [(1, 3, 6), (0, 2, 4), (0, 10, 5, False)])
    store = ActivationStore.open(path)
    keys = [e.key for e in store.episodes()]
    assert keys == ["t00_i02_a00", "t00_i10_a00", "t01_i03_a00"]
    assert [e.key for e in store.episodes(success_only=True)] == ["t00_i02_a00", "t01_i03_a00"]
    assert (
        store.num_hidden_states == LAYERS and store.hidden_size == HIDDEN and store.pooling == "last_prompt"
    )
    assert store.atom_names == ATOMS and store.model_id == "tiny-test"

    for layer in (0, 3):
        got = store.layer(layer)
        assert got.dtype == np.float16 and got.shape == (15, HIDDEN)
        np.testing.assert_array_equal(got, np.concatenate([written[k]["hidden"][layer] for k in keys]))
    order = ["t01_i03_a00", "t00_i02_a00"]
    np.testing.assert_array_equal(
        store.layer(2, order), np.concatenate([written[k]["hidden"][2] for k in order])
    )
    labels = store.labels("object", order)
    assert labels.dtype == bool and labels.shape == (10, 9)
    np.testing.assert_array_equal(labels, np.concatenate([written[k]["object_atoms"] for k in order]))
    np.testing.assert_array_equal(
        store.labels("action"), np.concatenate([written[k]["action_atoms"] for k in keys])
    )
    position, step = store.step_index(order)
    np.testing.assert_array_equal(position, [0] * 6 + [1] * 4)
    np.testing.assert_array_equal(step, [*range(6), *range(4)])

    ep = store.episode("t00_i10_a00")
    assert set(ep) >= {"hidden", "image", "action", "step", "world/pos"}
    np.testing.assert_array_equal(ep["world/pos"], written["t00_i10_a00"]["world/pos"])
    assert ep.attrs["instruction"] == "task 0" and ep.attrs["success"] is False
    seen = [(info.key, arrays["image"].shape) for info, arrays in store.iter_episodes(success_only=True)]
    assert seen == [("t00_i02_a00", (4, 8, 8, 3)), ("t01_i03_a00", (6, 8, 8, 3))]

    with pytest.raises(VlaprobeError, match="hidden state 5 does not exist"):
        store.layer(LAYERS)
    with pytest.raises(VlaprobeError, match="no episode 't09_i00_a00'"):
        store.labels("object", ["t09_i00_a00"])


def test_layer_reads_only_its_chunk(tmp_path: Path) -> None:
    path = tmp_path / "store"
    write(path, [(0, 0, 5), (0, 1, 3)])
    chunk_files = sorted((path / "episodes/t00_i00_a00/hidden").glob("c.*"))
    assert [p.name for p in chunk_files] == [f"c.{i}.0.0" for i in range(LAYERS)]  # one file per layer
    # Destroy every other layer's chunks: layer 2 must still read (it never touches them).
    for ep in ("t00_i00_a00", "t00_i01_a00"):
        for layer in set(range(LAYERS)) - {2}:
            (path / f"episodes/{ep}/hidden/c.{layer}.0.0").write_bytes(b"garbage")
    assert ActivationStore.open(path).layer(2).shape == (8, HIDDEN)
    with pytest.raises(Exception):  # noqa: B017 - any decoding error proves the chunk was read
        ActivationStore.open(path).layer(1)


def test_action_token_pooling_layers(tmp_path: Path) -> None:
    path = tmp_path / "store"
    written = write(path, [(0, 0, 4, True, "action_tokens")], make_meta(pooling="action_tokens"))
    got = ActivationStore.open(path).layer(1)
    assert got.shape == (4, 7, HIDDEN)
    np.testing.assert_array_equal(got, written["t00_i00_a00"]["hidden"][1])


def test_plain_zarr_reads_the_store(tmp_path: Path) -> None:
    path = tmp_path / "store"
    written = write(path, [(2, 5, 3)])
    root = zarr.open_group(path, mode="r")
    assert root.attrs["format"] == "vlaprobe-activations" and root.attrs["format_version"] == FORMAT_VERSION
    ep = root["episodes"]["t02_i05_a00"]
    assert ep.attrs["task"] == 2 and ep.attrs["length"] == 3
    np.testing.assert_array_equal(ep["hidden"][4], written["t02_i05_a00"]["hidden"][4])
    assert ep["object_atoms"].attrs["atom_names"] == ATOMS["object"]
    assert list(root["episodes"].keys()) == ["t02_i05_a00"]


def test_staged_episode_is_invisible_and_cleaned(tmp_path: Path) -> None:
    path = tmp_path / "store"
    write(path, [(0, 0, 3)])
    w = StoreWriter.open(path, make_meta())
    staged = w.stage(*make_episode(0, 1, 4))
    assert staged.path.is_dir() and path in staged.path.parents
    # Written and flushed but not published: neither our reader nor plain zarr sees it.
    assert [e.key for e in ActivationStore.open(path).episodes()] == ["t00_i00_a00"]
    assert list(zarr.open_group(path / "episodes", mode="r").keys()) == ["t00_i00_a00"]
    assert set(w.outcomes()) == {"t00_i00_a00"}
    assert w._lock is not None
    os.close(w._lock._fd)  # die without cleaning up, as after kill -9 (the lock goes with the process)
    assert staged.path.exists()
    with StoreWriter.open(path, make_meta()) as w2:
        assert not staged.path.exists() and not (path / ".staging").exists()
        w2.publish(w2.stage(*make_episode(0, 1, 4)))
    assert [e.key for e in ActivationStore.open(path).episodes()] == ["t00_i00_a00", "t00_i01_a00"]


def test_failure_markers_and_duplicates(tmp_path: Path) -> None:
    path = tmp_path / "store"
    with StoreWriter.open(path, make_meta()) as w:
        w.write_episode(*make_episode(0, 0, 3))
        info, _ = make_episode(0, 1, 9, success=False)
        w.mark_failed(info)
        assert {k: e.success for k, e in w.outcomes().items()} == {"t00_i00_a00": True, "t00_i01_a00": False}
        with pytest.raises(VlaprobeError, match="already has episodes/t00_i00_a00"):
            w.write_episode(*make_episode(0, 0, 3))
        assert not any((path / ".staging").iterdir())
    store = ActivationStore.open(path)
    assert [e.key for e in store.episodes()] == ["t00_i00_a00"]
    assert [e.key for e in store.failures()] == ["t00_i01_a00"]


def test_second_writer_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "store"
    with (
        StoreWriter.open(path, make_meta()),
        pytest.raises(VlaprobeError, match=f"is being written by pid {os.getpid()}"),
    ):
        StoreWriter.open(path, make_meta())
    StoreWriter.open(path, make_meta()).close()  # released


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"pooling": "mean"}, r"pooling is \"last_prompt\" in the store but \"mean\" in this run"),
        ({"driver": "policy"}, "driver is"),
        ({"model": {"name": "tiny", "layers": 6}}, "model.layers is 5 in the store but 6"),
        ({"atom_names": {**ATOMS, "action": ["grasped(o1)", "grasped(o0)"]}}, r"atom vocabulary.action\[0\]"),
    ],
)
def test_incompatible_run_is_refused(tmp_path: Path, change: dict, message: str) -> None:
    path = tmp_path / "store"
    write(path, [(0, 0, 2)])
    with pytest.raises(VlaprobeError, match=message) as err:
        StoreWriter.open(path, make_meta(**change))
    assert "\n" not in str(err.value) and "another --out" in str(err.value)


def test_not_a_store_and_wrong_version(tmp_path: Path) -> None:
    with pytest.raises(VlaprobeError, match="does not exist"):
        ActivationStore.open(tmp_path / "missing")
    (tmp_path / "plain").mkdir()
    (tmp_path / "plain" / "notes.txt").write_text("hello")
    for target in (tmp_path / "plain", tmp_path / "plain" / "notes.txt"):
        with pytest.raises(VlaprobeError, match="is not an activation store") as err:
            ActivationStore.open(target)
        assert "\n" not in str(err.value)
    with pytest.raises(VlaprobeError, match="choose a new or empty folder"):
        StoreWriter.open(tmp_path / "plain", make_meta())
    zarr.open_group(tmp_path / "other", mode="w", attributes={"x": 1})
    with pytest.raises(VlaprobeError, match="is not an activation store"):
        ActivationStore.open(tmp_path / "other")

    path = tmp_path / "store"
    write(path, [(0, 0, 2)])
    meta_file = path / "zarr.json"
    doc = json.loads(meta_file.read_text())
    doc["attributes"]["format_version"] = FORMAT_VERSION + 1
    meta_file.write_text(json.dumps(doc))
    for opener in (ActivationStore.open, lambda p: StoreWriter.open(p, make_meta())):
        with pytest.raises(VlaprobeError, match=f"format_version {FORMAT_VERSION + 1}, this vlaprobe reads"):
            opener(path)


def test_empty_existing_folder_becomes_a_store(tmp_path: Path) -> None:
    path = tmp_path / "empty"
    path.mkdir()
    write(path, [(0, 0, 2)])
    assert len(ActivationStore.open(path).episodes()) == 1
    assert not list(tmp_path.glob(".*partial"))


def test_update_meta_keeps_the_rest(tmp_path: Path) -> None:
    path = tmp_path / "store"
    with StoreWriter.open(path, make_meta(extra="kept")) as w:
        w.update_meta(runs=[{"command": "a"}])
    meta = ActivationStore.open(path).meta
    assert meta["runs"] == [{"command": "a"}] and meta["extra"] == "kept" and meta["pooling"] == "last_prompt"


def test_typed_metadata_reads_what_the_writer_wrote_and_defaults_what_older_stores_lack(
    tmp_path: Path,
) -> None:
    path = tmp_path / "store"
    made = make_meta(
        driver="dagger", instructions={"0": "put the bowl on the plate"}, created="2026-12-03T10:00:00"
    )
    with StoreWriter.open(path, made):
        pass
    meta = read_store_meta(path)
    assert meta == ActivationStore.open(path).metadata and meta.format_version == FORMAT_VERSION
    assert (meta.driver, meta.instructions, meta.perturb) == (
        "dagger",
        {"0": "put the bowl on the plate"},
        None,
    )
    assert meta.atom_names == ActivationStore.open(path).atom_names and meta.created == made["created"]
    older = tmp_path / "older"  # a store written before the driver and the instructions were recorded
    with StoreWriter.open(older, make_meta()):
        pass
    doc = json.loads((older / "zarr.json").read_text())
    for key in ("driver", "instructions", "created"):
        doc["attributes"].pop(key, None)
    (older / "zarr.json").write_text(json.dumps(doc))
    meta = read_store_meta(older)
    assert (meta.driver, meta.instructions, meta.created) == (None, {}, "")


def test_success_step_round_trips_and_older_episodes_read_it_as_their_last_row() -> None:
    info = EpisodeInfo(
        key="t00_i00_a00", task=0, init=0, attempt=0, success=True, length=9, seed=1, driver="expert",
        success_step=5,
    )  # fmt: skip
    assert EpisodeInfo.from_attrs(json.loads(json.dumps(info.attrs()))) == info
    legacy = {k: v for k, v in info.attrs().items() if k != "success_step"}
    assert EpisodeInfo.from_attrs(legacy).success_step == 8
    assert EpisodeInfo.from_attrs({**legacy, "success": False}).success_step is None
