"""Damaged stores: `info` names the damage, `train` refuses it, `collect` says how to repair (issue #10)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from tests.collection.fakes import make_fake_worker
from tests.collection.test_collect import config
from tests.collection.test_store import write

from vlaprobe.collection.collect import collect
from vlaprobe.collection.info import info
from vlaprobe.collection.store import ActivationStore
from vlaprobe.collection.verify import check_store
from vlaprobe.configs.collect import InfoConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.data import load_store

KEY = "t00_i01_a00"


def _delete_chunk(store: Path) -> None:
    (store / "episodes" / KEY / "hidden" / "c.2.0.0").unlink()


def _truncate_chunk(store: Path) -> None:
    chunk = store / "episodes" / KEY / "hidden" / "c.2.0.0"
    chunk.write_bytes(chunk.read_bytes()[:10])


def _delete_episode_meta(store: Path) -> None:
    (store / "episodes" / KEY / "zarr.json").unlink()


def _edit_length(store: Path) -> None:
    path = store / "episodes" / KEY / "zarr.json"
    meta = json.loads(path.read_text())
    meta["attributes"]["length"] += 1
    path.write_text(json.dumps(meta))


def _edit_layers(store: Path) -> None:
    path = store / "zarr.json"
    meta = json.loads(path.read_text())
    meta["attributes"]["num_hidden_states"] = 3
    path.write_text(json.dumps(meta))


def _bad_array_meta(store: Path) -> None:
    (store / "episodes" / KEY / "object_atoms" / "zarr.json").write_text("{not json")


def _delete_array(store: Path) -> None:
    shutil.rmtree(store / "episodes" / KEY / "world" / "pos")


def _delete_zero_chunk(store: Path) -> None:
    # step is 0.. per episode; the world array of steps: a chunk equal to the fill value is written too
    (store / "episodes" / KEY / "step" / "c.0").unlink()


DAMAGE: dict[str, tuple[Callable[[Path], None], str]] = {
    "deleted chunk": (_delete_chunk, "hidden: chunk file c.2.0.0 missing"),
    "episode metadata deleted": (_delete_episode_meta, "episode metadata (zarr.json) missing"),
    "length edited": (_edit_length, "the episode metadata say"),
    "num_hidden_states edited": (_edit_layers, "but the metadata say 3 hidden states"),
    "bad array metadata": (_bad_array_meta, "object_atoms: array metadata unreadable"),
    "deleted array": (_delete_array, "array(s) world/pos missing"),
    "deleted chunk of another array": (_delete_zero_chunk, "step: chunk file c.0 missing"),
}


@pytest.fixture
def store(tmp_path: Path) -> Path:
    path = tmp_path / "store"
    write(path, [(0, 0, 6), (0, 1, 5), (1, 0, 4), (1, 1, 7)])
    return path


@pytest.mark.parametrize("case", list(DAMAGE))
def test_damage_is_named_by_info_and_refused_by_train(store: Path, case: str) -> None:
    damage, problem = DAMAGE[case]
    assert check_store(store) == []
    damage(store)
    found = check_store(store)
    every = sorted(p.name for p in (store / "episodes").iterdir() if p.is_dir())
    assert [d.key for d in found] == (every if case == "num_hidden_states edited" else [KEY])
    assert problem in found[0].problem
    with pytest.raises(
        VlaprobeError, match=rf"damaged episode\(s\).*{KEY if found[0].key == KEY else ''}.*rm -r"
    ):
        info(InfoConfig(path=store, json=True))
    with pytest.raises(VlaprobeError, match="damaged"):
        load_store(store)


def test_truncated_chunk_found_by_verify_and_by_reading(store: Path) -> None:
    _truncate_chunk(store)
    assert check_store(store) == []  # the cheap check only lists files
    assert info(InfoConfig(path=store, json=True)) == 0
    with pytest.raises(VlaprobeError, match=f"{KEY}: hidden: cannot be read"):
        info(InfoConfig(path=store, verify=True))
    with pytest.raises(VlaprobeError, match=f"episode {KEY} is damaged .*info --verify"):
        ActivationStore.open(store).layer(2)
    with pytest.raises(VlaprobeError, match="damaged"):
        load_store(store)


def test_collect_resume_says_how_to_repair(tmp_path: Path) -> None:
    cfg = config(tmp_path / "store")
    collect(cfg, make_fake_worker)
    key = sorted(p.name for p in (cfg.out / "episodes").iterdir())[0]
    (cfg.out / "episodes" / key / "zarr.json").unlink()
    with pytest.raises(VlaprobeError, match=rf"{key}: episode metadata.*rm -r \S+/episodes/{key}.*rerun"):
        collect(cfg, make_fake_worker)
    shutil.rmtree(cfg.out / "episodes" / key)  # the repair the message names
    collect(cfg, make_fake_worker)
    assert check_store(cfg.out, read=True) == []
    assert key in {e.key for e in ActivationStore.open(cfg.out).episodes()}


def test_damaged_array_read_by_name_is_one_line(store: Path) -> None:
    _truncate_chunk(store)
    arrays = ActivationStore.open(store).episode(KEY)
    with pytest.raises(VlaprobeError, match=f"episodes/{KEY} is damaged \\(hidden"):
        arrays["hidden"]
