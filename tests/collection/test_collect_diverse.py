"""Collection with --perturb on the fakes: perturbation rows and episode marks in the store, diversity figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tests.collection.fakes import make_fake_worker

from vlaprobe.collection.collect import collect
from vlaprobe.collection.diversity import store_diversity
from vlaprobe.collection.store import ActivationStore
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.configs.env import EnvConfig
from vlaprobe.rollout.perturb import KIND_CODE


def test_perturbed_rows_and_episodes_are_marked(tmp_path: Path) -> None:
    cfg = CollectConfig(
        out=tmp_path / "store",
        tasks=(0, 1),
        episodes_per_task=2,
        max_tries_per_task=8,
        progress=False,
        perturb="displace=1",
        env=EnvConfig(max_steps=30, image_size=16),
    )
    collect(cfg, make_fake_worker)
    store = ActivationStore.open(cfg.out)
    assert store.meta["perturb"] == "displace=1"
    for info in store.episodes():
        arrays = store.episode(info.key)
        marks = arrays.attrs["perturbations"]
        codes = arrays["perturbation"]
        assert codes.shape == (info.length,) and codes.dtype == np.int8
        rows = np.flatnonzero(codes)
        assert [m["kind"] for m in marks] == ["displace"] * len(rows)
        assert rows.tolist() == [m["row"] for m in marks]
        assert set(codes[rows].tolist()) <= {KIND_CODE["displace"]}
        # every episode drew one displacement: it happened, or the episode says why not
        missed = arrays.attributes.perturbations_missed
        assert missed is not None and len(marks) + len(missed) == 1
        assert all(m.kind == "displace" and m.reason.startswith("never due: ") for m in missed)
    d = store_diversity(cfg.out)
    assert d.perturbed_episodes > 0
    assert d.applied == {"displace": d.perturbed_episodes}
    # the fakes' seeds give both: episodes displaced, and episodes grasped before their displacement's row
    assert 0 < d.perturbed_episodes < d.episodes
    assert d.missed == {"displace: never due": d.episodes - d.perturbed_episodes}
    assert d.episodes == len(store.episodes()) and d.perturbed_episodes == sum(
        bool(store.episode(e.key).attrs["perturbations"]) for e in store.episodes()
    )


def test_unperturbed_stores_keep_their_arrays_and_attributes(tmp_path: Path) -> None:
    cfg = CollectConfig(
        out=tmp_path / "store",
        tasks=(0,),
        episodes_per_task=1,
        max_tries_per_task=8,
        progress=False,
        env=EnvConfig(max_steps=6, image_size=16),
    )
    collect(cfg, make_fake_worker)
    store = ActivationStore.open(cfg.out)
    (info,) = store.episodes()
    arrays = store.episode(info.key)
    assert (
        "perturbation" not in arrays and "perturbations" not in arrays.attrs and "perturb" not in store.meta
    )
    assert "perturbations_missed" not in arrays.attrs and arrays.attributes.perturbations_missed is None
