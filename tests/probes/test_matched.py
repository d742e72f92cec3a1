"""The matched-steps control (an AUC within task x time cells) on data with a known answer, and in evaluation.json."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from vlaprobe.configs.train import TrainConfig
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.bootstrap import bootstrap_weights, interval
from vlaprobe.probes.families import FAMILIES, family_columns, family_of
from vlaprobe.probes.matched import matched_auc, pair_counts
from vlaprobe.probes.results import EVALUATION_FILE, read_evaluation


def _auc(scores: np.ndarray, truth: np.ndarray, cells: np.ndarray, groups: np.ndarray, resamples: int = 0):
    """Point and resamples of the within-cell AUC of one layer and the atoms of ``truth`` (rows, atoms)."""
    g = int(groups.max()) + 1
    correct, pairs = pair_counts(torch.as_tensor(scores)[None], truth, cells, groups, g)
    return matched_auc(correct, pairs, bootstrap_weights(g, resamples, 0))


def _cells(rng: np.random.Generator, rows: int = 2000, episodes: int = 20, cells: int = 10):
    groups = np.sort(rng.integers(0, episodes, rows))
    return rng.integers(0, cells, rows), groups


def test_a_hand_computed_cell() -> None:
    # Cell 0: true at rows 0, 1 (scores 3, 1), false at rows 2, 3 (scores 2, 1): pairs (3>2) (3>1) (1<2) (1=1).
    # Cell 1 holds one true row scored below every false row of cell 0: it pairs with nothing.
    scores = np.array([[3.0], [1.0], [2.0], [1.0], [-10.0]], np.float32)
    truth = np.array([[True], [True], [False], [False], [True]])
    cells, groups = np.array([0, 0, 0, 0, 1]), np.array([0, 1, 0, 1, 1])
    correct, pairs = pair_counts(torch.as_tensor(scores)[None], truth, cells, groups, 2)
    assert pairs[0].tolist() == [[1, 1], [1, 1]]  # one pair per (true row's episode, false row's episode)
    assert correct[0, 0].tolist() == [[1.0, 1.0], [0.0, 0.5]]
    point, _ = matched_auc(correct, pairs, np.ones((1, 2)))
    assert point[0, 0] == pytest.approx(2.5 / 4)
    # A resample drawing episode 0 twice and episode 1 never: rows 0 and 2 only, each pair 4 times: 1.0.
    _, res = matched_auc(correct, pairs, np.array([[2.0, 0.0], [0.0, 2.0]]))
    assert res[:, 0, 0].tolist() == [1.0, 0.5]  # episode 1 alone: rows 1 and 3 tie


def test_a_score_equal_to_the_label_ranks_every_pair() -> None:
    rng = np.random.default_rng(0)
    cells, groups = _cells(rng)
    truth = rng.random((len(cells), 3)) < 0.4
    point, res = _auc(truth.astype(np.float32), truth, cells, groups, 200)
    assert point[0].tolist() == [1.0, 1.0, 1.0]
    assert np.all(res == 1.0)


def test_a_score_independent_of_the_label_is_at_chance_within_its_interval() -> None:
    rng = np.random.default_rng(1)
    cells, groups = _cells(rng)
    truth = rng.random((len(cells), 1)) < 0.3
    point, res = _auc(rng.normal(size=(len(cells), 1)).astype(np.float32), truth, cells, groups, 500)
    low, high = interval(res[:, 0, 0])
    assert low < 0.5 < high and abs(point[0, 0] - 0.5) < 0.05


def test_the_cell_is_what_a_score_may_not_use() -> None:
    # The label is the cell's majority plus noise and the score is the cell's share of true rows: it ranks
    # every pair of different cells, and no pair within one: exactly 1/2.
    rng = np.random.default_rng(2)
    cells, groups = _cells(rng)
    truth = (rng.random((len(cells), 1)) < (cells / 10)[:, None]).astype(bool)
    point, _ = _auc((cells / 10)[:, None].astype(np.float32), truth, cells, groups)
    assert point[0, 0] == 0.5


def test_an_atom_constant_within_every_cell_has_no_pairs() -> None:
    cells, groups = np.repeat(np.arange(4), 5), np.repeat(np.arange(4), 5)
    truth = (cells % 2 == 0)[:, None]
    point, res = _auc(np.zeros((20, 1), np.float32), truth, cells, groups, 10)
    assert np.isnan(point).all() and np.isnan(res).all()


def test_families() -> None:
    assert family_of("on(akita_black_bowl_1,plate_1)") == "on(bowl, plate)"
    assert family_of("on(cookies_1,plate_1)") == "other object state"
    assert family_of("left-of(a,b)") == "relations"
    assert family_of("grasped(a)") == "grasped"
    atoms = ["should-move-towards(a)", "grasped(b)", "grasped(a)"]
    assert {k: v.tolist() for k, v in family_columns(atoms).items()} == {
        "grasped": [1, 2],
        "should-move-towards": [0],
    }
    assert list(family_columns(atoms)) == [f for f in FAMILIES if f in ("grasped", "should-move-towards")]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data = synthetic_data(
        num_tasks=3, episodes_per_task=5, steps_per_episode=30, num_layers=3, hidden_size=32, signal=8.0
    )
    noise = torch.randn(data.hidden.shape, generator=torch.Generator().manual_seed(0)).to(data.hidden.dtype)
    control = dataclasses.replace(data, hidden=noise, model_id="untrained")
    cfg = TrainConfig(bootstrap=200, auprc_bootstrap=0, shuffled_control=False, conditional=True)
    return train_on_data(data, cfg, tmp_path_factory.mktemp("probes"), observer=control)


def test_train_writes_the_matched_control_against_the_observer(trained: Path) -> None:
    evaluation = read_evaluation(trained)
    for h in evaluation.heads.values():
        m = h.matched
        assert m is not None and m.paired and m.difference is not None
        assert len(m.pairs) == len(h.atoms) and len(m.probe.atom.value) == len(evaluation.layers)
        assert list(h.families) == [f for f in FAMILIES if f in h.families]
        assert sorted(a for atoms in h.families.values() for a in atoms) == sorted(h.atoms)
        assert len(m.family.value[0]) == len(h.families)
        assert set(h.conditional_families) == {"task", "task_time"}
        for i, v in enumerate(m.probe.layer.value):
            o, d = m.observer.layer.value[i], m.difference.layer.value[i]  # type: ignore[union-attr]
            if v is not None and o is not None:
                assert d == pytest.approx(v - o, abs=2e-5)
                assert m.probe.layer.low[i] <= v <= m.probe.layer.high[i]
    # Planted linear labels: the probes rank matched pairs far better than noise does.
    obj = evaluation.heads["object"].matched
    assert obj is not None and obj.difference is not None
    assert max(v for v in obj.difference.layer.low if v is not None) > 0


def test_a_version_4_evaluation_still_reads(trained: Path, tmp_path: Path) -> None:
    data = json.loads((trained / EVALUATION_FILE).read_text())
    data["format_version"] = 4
    for h in data["heads"].values():
        for key in ("families", "matched", "conditional_families"):
            del h[key]
    (tmp_path / EVALUATION_FILE).write_text(json.dumps(data))
    old = read_evaluation(tmp_path)
    assert all(h.matched is None and h.families == {} for h in old.heads.values())
