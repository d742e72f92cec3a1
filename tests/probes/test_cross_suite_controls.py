"""The controls of `vlaprobe cross-suite` on stores written by the real writer and probes trained by `vlaprobe
train`: the shuffled-label control is train's own (same rows, permutations and C: the same figure on the source's
test split), sits at chance where the hidden states encode the atoms and next to the probes where they encode
nothing; the control observer is scored on its own target store, paired over the same episodes; the result file
reads version 1; every refusal is one line with exit 2."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch
from tests.envs.test_assets import REAL_ASSETS
from tests.probes.test_cross_suite import GOAL, SPATIAL, write_store
from tests.test_cli_errors import one_line_error

from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.configs.train import ProbeConfig, SplitConfig, TrainConfig
from vlaprobe.probes.bootstrap import bootstrap_weights, nan_mean
from vlaprobe.probes.cross_suite import cross_suite
from vlaprobe.probes.cross_suite_controls import fit_shuffled, source_rows
from vlaprobe.probes.cross_suite_inputs import Target
from vlaprobe.probes.cross_suite_result import read_cross_suite, table_lines, write_cross_suite
from vlaprobe.probes.data import load_store
from vlaprobe.probes.probeset import ProbeSet
from vlaprobe.probes.results import read_evaluation
from vlaprobe.probes.split import rows_of
from vlaprobe.probes.train import train_probes

pytestmark = pytest.mark.skipif(not REAL_ASSETS, reason="needs LIBERO's assets (VLAPROBE_LIBERO_ASSETS)")

NOISE = {"object": 0.0, "action": 0.0}
"""Hidden states that hold no label: labels independent of them."""


def train(store: Path, out: Path, by: str = "episode", permutations: int = 2) -> Path:
    cfg = TrainConfig(
        store=store, out=out, bootstrap=50, auprc_bootstrap=0, shuffled_permutations=permutations,
        split=SplitConfig(by=by), probe=ProbeConfig(c_grid=(1.0,)),  # type: ignore[arg-type]
    )  # fmt: skip
    return train_probes(cfg)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Spatial probes of the observed network (within-task split) and of a control network whose hidden states
    hold nothing; the goal stores both networks observed (the same episodes)."""
    root = tmp_path_factory.mktemp("runs")
    source = write_store(root / "sa", "libero_spatial", SPATIAL, [0, 1, 2, 3])
    control = write_store(root / "ca", "libero_spatial", SPATIAL, [0, 1, 2, 3], sign=NOISE, model_id="init")
    return {
        "probes": train(source, root / "sp"),
        "control_probes": train(control, root / "cp"),
        "goal": write_store(root / "ga", "libero_goal", GOAL, [0, 1, 2]),
        "control_goal": write_store(
            root / "cga", "libero_goal", GOAL, [0, 1, 2], sign=NOISE, model_id="init"
        ),
    }


def test_the_shuffled_probes_are_trains_own(runs: dict[str, Path]) -> None:
    """Fit on the same rows with the same permutations and C, the control scores on the source's test split
    what `vlaprobe train`'s shuffled control scored there."""
    probes = ProbeSet.load(runs["probes"])
    ev = read_evaluation(runs["probes"])
    src = runs["probes"].parent / "sa"
    data = load_store(src, heads=["object"], layers=[0, 1, 2])
    rows, how = source_rows(probes, data)
    assert len(rows) == ev.split.train.steps and "training split" in how
    test = [data.episode_keys.index(k) for k in ev.split.test_episodes]
    test_rows = rows_of(data.episode, np.array(sorted(test)))
    assert not np.isin(rows, test_rows).any()
    shuffled = fit_shuffled(probes, src, {"object": probes.atoms("object")}, [0, 1, 2], 2)
    assert shuffled.info.seed == probes.meta.seeds["shuffle"] and np.all(shuffled.c["object"] == 1.0)
    weights = bootstrap_weights(len(test), 10, 0)
    episode = np.unique(data.episode[test_rows], return_inverse=True)[1]
    cols = [data.atom_names["object"].index(a) for a in probes.atoms("object")]
    truth = data.labels["object"][test_rows][:, cols]
    scorer = Target(truth, np.ones_like(truth), episode, len(test), weights)
    hidden = data.hidden[:, torch.as_tensor(test_rows)]
    runs_ = [scorer.score(x > 0) for x in shuffled.logits(hidden, "object")]
    mine = nan_mean(np.mean([r.point for r in runs_], 0), 1)
    control = ev.heads["object"].control
    assert control is not None
    theirs = control["balanced_accuracy"].layer.value
    assert mine == pytest.approx(theirs, abs=1e-6)  # the same figure, to its rounding


def test_shuffled_at_chance_where_the_states_encode_the_atoms(runs: dict[str, Path], tmp_path: Path) -> None:
    r = cross_suite(CrossSuiteConfig(probes=runs["probes"], store=runs["goal"], bootstrap=100))
    assert r.shuffled is not None and r.shuffled.permutations == 5 and "training split" in r.shuffled.rows
    obj = r.heads["object"]
    layers = {s.layer for s in obj.shuffled}
    assert layers == {obj.source_layer, obj.best_layer} and len(obj.shuffled) == len(layers)
    for s in obj.shuffled:
        assert s.balanced_accuracy.value is not None and abs(s.balanced_accuracy.value - 0.5) < 0.1
        assert s.spread is not None and s.c == 1.0
        probe = obj.balanced_accuracy[obj.layers.index(s.layer)].value
        assert probe is not None
        assert s.probe_minus_shuffled.value == pytest.approx(probe - s.balanced_accuracy.value, abs=2e-6)
        assert s.probe_minus_shuffled.low is not None and s.probe_minus_shuffled.low > 0.3
    assert obj.observer is None and r.control is None
    off = cross_suite(
        CrossSuiteConfig(probes=runs["probes"], store=runs["goal"], bootstrap=100, shuffled_control=False)
    )
    assert off.shuffled is None and off.heads["object"].shuffled == []
    assert off.heads["object"].balanced_accuracy == obj.balanced_accuracy


def test_shuffled_next_to_the_probes_where_the_states_hold_nothing(tmp_path: Path) -> None:
    """Labels independent of the hidden states: the probes learn what the shuffled labels teach, nothing."""
    source = write_store(tmp_path / "sa", "libero_spatial", SPATIAL, [0, 1, 2, 3], sign=NOISE)
    probes = train(source, tmp_path / "sp", by="leave-one-task-out")
    goal = write_store(tmp_path / "ga", "libero_goal", GOAL, [0, 1, 2], sign=NOISE)
    r = cross_suite(CrossSuiteConfig(probes=probes, store=goal, bootstrap=200))
    assert r.shuffled is not None and "every row" in r.shuffled.rows
    for h in r.heads.values():
        for s in h.shuffled:
            d = s.probe_minus_shuffled
            assert d.value is not None and d.low is not None and d.high is not None
            assert abs(d.value) < 0.08 and d.low < 0 < d.high


def test_the_control_observer_is_paired_on_its_own_target_store(
    runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cli import main

    out = tmp_path / "x.json"
    args = [
        "cross-suite",
        "--probes",
        str(runs["probes"]),
        "--store",
        str(runs["goal"]),
        "--bootstrap",
        "100",
    ]
    control = ["--control-probes", str(runs["control_probes"]), "--control-store", str(runs["control_goal"])]
    assert main([*args, *control, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "shuffled labels at layer" in text and "control observer init" in text
    r = read_cross_suite(out)
    assert json.loads(out.read_text())["format_version"] == 2
    assert r.control is not None and r.control.model_id == "init"
    obj = r.heads["object"]
    o = obj.observer
    assert (
        o is not None
        and o.atoms == obj.atoms
        and o.source_layer == ProbeSet.load(runs["control_probes"]).best_layer("object")
    )
    assert o.at_source_layer.value is not None and abs(o.at_source_layer.value - 0.5) < 0.1  # it saw nothing
    mine = obj.at_source_layer.value
    assert mine is not None and o.probe_minus_observer.value == pytest.approx(
        mine - o.at_source_layer.value, abs=2e-6
    )
    assert o.probe_minus_observer.low is not None and o.probe_minus_observer.low > 0.3
    best = o.balanced_accuracy[o.layers.index(o.best_layer)].value
    assert best is not None and o.best_layer in o.tied
    assert o.best_minus_best.value == pytest.approx(
        obj.balanced_accuracy[obj.layers.index(obj.best_layer)].value - best,
        abs=2e-6,  # type: ignore[operator]
    )


def test_a_version_1_file_reads_without_controls(runs: dict[str, Path], tmp_path: Path) -> None:
    r = cross_suite(CrossSuiteConfig(probes=runs["probes"], store=runs["goal"], bootstrap=20))
    path = write_cross_suite(tmp_path / "v2.json", r)
    data = json.loads(path.read_text())
    del data["shuffled"], data["control"]
    for h in data["heads"].values():
        del h["shuffled"], h["observer"]
    data["format_version"] = 1
    old = tmp_path / "v1.json"
    old.write_text(json.dumps(data))
    v1 = read_cross_suite(old)
    assert v1.shuffled is None and all(h.shuffled == [] and h.observer is None for h in v1.heads.values())
    assert asdict(v1.heads["object"])["balanced_accuracy"] == asdict(r.heads["object"])["balanced_accuracy"]
    assert not any("shuffled labels" in line for line in table_lines(v1))


def test_control_refusals_are_one_line(
    runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["cross-suite", "--probes", str(runs["probes"]), "--store", str(runs["goal"]), "--bootstrap", "20"]
    cp, cs = ["--control-probes", str(runs["control_probes"])], ["--control-store", str(runs["control_goal"])]
    assert "go together" in one_line_error(capsys, [*base, *cp])
    assert "go together" in one_line_error(capsys, [*base, *cs])
    same = ["--control-probes", str(runs["probes"])]
    assert "same model" in one_line_error(capsys, [*base, *same, *cs])
    fewer = write_store(tmp_path / "f", "libero_goal", GOAL, [0, 1], sign=NOISE, model_id="init")
    assert "other episodes" in one_line_error(capsys, [*base, *cp, "--control-store", str(fewer)])
    other = write_store(tmp_path / "o", "libero_goal", GOAL, [0, 1, 2], model_id="other")
    assert "observed by model 'other'" in one_line_error(capsys, [*base, *cp, "--control-store", str(other)])
    objects = write_store(tmp_path / "b", "libero_object", GOAL, [0, 1, 2], model_id="init")
    assert "libero_object store" in one_line_error(capsys, [*base, *cp, "--control-store", str(objects)])
    goal_probes = train(runs["control_goal"], tmp_path / "gp", permutations=1)
    err = one_line_error(capsys, [*base, "--control-probes", str(goal_probes), *cs])
    assert "trained on libero_goal" in err
    assert "at least 1" in one_line_error(capsys, [*base, "--shuffled-permutations", "0"])


def test_a_source_store_of_other_episodes_is_refused(
    runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Within-task probes: the shuffled control refits on their training split, which another store of the same
    suite and model does not give."""
    other = write_store(tmp_path / "s", "libero_spatial", SPATIAL, [0, 1, 2])
    base = ["cross-suite", "--probes", str(runs["probes"]), "--store", str(runs["goal"]), "--bootstrap", "20"]
    assert "another test split" in one_line_error(capsys, [*base, "--source-store", str(other)])
