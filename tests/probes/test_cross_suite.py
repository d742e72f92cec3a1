"""`vlaprobe cross-suite` on stores written by the real writer and probes trained by `vlaprobe train`: atoms the
hidden states encode alike in both suites transfer, atoms encoded with the opposite sign fall below chance,
atoms a target task does not define are masked, and every refusal is one line with exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tests.envs.test_assets import REAL_ASSETS
from tests.test_cli_errors import one_line_error

from vlaprobe.collection.store import EpisodeInfo, episode_key
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.configs.cross_suite import CrossSuiteConfig
from vlaprobe.configs.train import ProbeConfig, SplitConfig, TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.cross_suite import cross_suite
from vlaprobe.probes.cross_suite_result import read_cross_suite
from vlaprobe.probes.results import read_evaluation
from vlaprobe.probes.train import train_probes

pytestmark = pytest.mark.skipif(not REAL_ASSETS, reason="needs LIBERO's assets (VLAPROBE_LIBERO_ASSETS)")

LAYERS, HIDDEN, STEPS = 3, 16, 30
BOWL_ON_PLATE = "on(akita_black_bowl_1,plate_1)"
BOTH = {
    "object": [BOWL_ON_PLATE, "on-table(plate_1)", "left-of(akita_black_bowl_1,plate_1)"],
    "action": ["grasped(akita_black_bowl_1)", "should-move-towards(plate_1)"],
}
"""Atoms of both suites' vocabularies."""
SPATIAL = {
    "object": [*BOTH["object"], "on(cookies_1,plate_1)"],
    "action": [*BOTH["action"], "grasped(cookies_1)"],
}
GOAL = {
    "object": [*BOTH["object"], "on(wine_bottle_1,plate_1)"],
    "action": [*BOTH["action"], "grasped(wine_bottle_1)"],
}
CHEESE = {"object": ["on-table(cream_cheese_1)"], "action": ["grasped(cream_cheese_1)"]}
"""cream_cheese_1 is in every LIBERO-goal task and in tasks 0-4 and 7 of LIBERO-object (not 5, 6, 8, 9)."""


def _direction(atom: str) -> np.ndarray:
    """One fixed unit direction per atom name, the same in every store."""
    v = np.random.default_rng(sum(map(ord, atom))).standard_normal(HIDDEN)
    return v / np.linalg.norm(v)


def write_store(
    path: Path,
    suite: str,
    atoms: dict[str, list[str]],
    tasks: list[int],
    sign: dict[str, float] | None = None,
    contrary: tuple[int, ...] = (),
    model_id: str = "synthetic",
    hidden: int = HIDDEN,
) -> Path:
    """3 episodes per task; each atom true on a random stretch of every episode. Layers 1 and 2 hold each atom's
    label along its direction times ``sign[head]`` (layer 0: noise only); in the tasks of ``contrary`` the
    stored labels are the opposite of what the hidden states hold."""
    rng = np.random.default_rng(len(tasks) + len(suite))
    meta = {
        "atom_names": atoms, "model_id": model_id, "model": {"model_id": model_id}, "num_hidden_states": LAYERS,
        "hidden_size": hidden, "pooling": "last_prompt", "driver": "expert", "suite": suite, "env": {},
        "seed": 0, "instructions": {str(t): f"task {t}" for t in tasks},
    }  # fmt: skip
    t = np.arange(STEPS)
    with StoreWriter.open(path, meta) as writer:
        for task in tasks:
            for init in range(3):
                x = rng.standard_normal((LAYERS, STEPS, hidden))
                arrays: dict[str, np.ndarray] = {}
                for head, names in atoms.items():
                    start = rng.integers(0, STEPS // 2, len(names))
                    length = rng.integers(STEPS // 4, STEPS // 2, len(names))
                    y = (t[:, None] >= start) & (t[:, None] < start + length)
                    scale = 6 * (sign or {}).get(head, 1.0)
                    for k, name in enumerate(names):
                        if hidden == HIDDEN:
                            x[1:] += scale * (y[:, k : k + 1] - 0.5) * _direction(name)
                    arrays[f"{head}_atoms"] = ~y if task in contrary else y
                key = episode_key(task, init)
                info = EpisodeInfo(key, task, init, 0, True, STEPS, seed=init, driver="expert")
                writer.write_episode(info, {"hidden": x.astype(np.float16), **arrays})
    return path


def train(store: Path, out: Path) -> Path:
    cfg = TrainConfig(
        store=store, out=out, bootstrap=50, auprc_bootstrap=0, shuffled_permutations=1,
        split=SplitConfig(by="leave-one-task-out"), probe=ProbeConfig(c_grid=(1.0,)),
    )  # fmt: skip
    return train_probes(cfg)


@pytest.fixture(scope="module")
def spatial(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("spatial")
    return train(write_store(root / "activations", "libero_spatial", SPATIAL, [0, 1, 2, 3]), root / "probes")


@pytest.fixture(scope="module")
def goal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Object atoms encoded as in the spatial store, action atoms with the opposite sign."""
    path = tmp_path_factory.mktemp("goal") / "activations"
    return write_store(path, "libero_goal", GOAL, [0, 1, 2], sign={"action": -1.0})


def test_shared_atoms_transfer_and_flipped_ones_fall_below_chance(spatial: Path, goal: Path) -> None:
    r = cross_suite(CrossSuiteConfig(probes=spatial, store=goal, bootstrap=200))
    assert (r.source_suite, r.target_suite) == ("libero_spatial", "libero_goal")
    assert (r.episodes, r.rows) == (9, 9 * STEPS)
    obj, act = r.heads["object"], r.heads["action"]
    assert obj.atoms == BOTH["object"] and act.atoms == BOTH["action"]
    assert r.unshared == {"object": ["on(cookies_1,plate_1)"], "action": ["grasped(cookies_1)"]}
    assert obj.masked_rows == 0 and obj.scored == 3
    assert obj.best_layer in (1, 2) and obj.best_layer in obj.tied and 0 not in obj.tied
    best = obj.balanced_accuracy[obj.layers.index(obj.best_layer)]
    assert best.value is not None and best.low is not None and best.value > 0.9 and best.low > 0.8
    assert obj.source_layer == read_evaluation(spatial).heads["object"].best.layer
    assert obj.at_source_layer == obj.balanced_accuracy[obj.layers.index(obj.source_layer)]
    layer0 = obj.balanced_accuracy[0].value
    assert layer0 is not None and abs(layer0 - 0.5) < 0.15  # noise only
    flipped = [e.value for e in act.balanced_accuracy[1:]]
    assert all(v is not None and v < 0.2 for v in flipped)
    for h in (obj, act):
        assert (h.majority.value, h.majority.low, h.majority.high) == (0.5, 0.5, 0.5)
        assert h.time.value is not None and 0.3 < h.time.value < 0.8
        best_value = h.balanced_accuracy[h.layers.index(h.best_layer)].value
        assert best_value is not None
        assert h.best_minus_time.value == pytest.approx(best_value - h.time.value, abs=1e-9)
    assert obj.best_minus_time.low is not None and obj.best_minus_time.low > 0
    fam = {f.family: f for f in obj.families}
    assert set(fam) == {"on(bowl, plate)", "relations", "other object state"}
    assert fam["on(bowl, plate)"].atoms == 1
    # The source figure is the evaluation's own, over the same atoms at the same layer.
    ev = read_evaluation(spatial).heads["object"]
    row = ev.probe["balanced_accuracy"].atom.value[obj.layers.index(obj.best_layer)]
    assert isinstance(row, list)
    mine = [row[ev.atoms.index(a)] for a in obj.atoms if a in ev.atoms]
    assert obj.source == pytest.approx(np.mean([v for v in mine if v is not None]), abs=1e-9)
    assert obj.source_split == "leave-one-task-out"


def test_undefined_atoms_are_masked(spatial: Path, tmp_path: Path) -> None:
    """cream_cheese_1 is not in LIBERO-object's task 5: its contrary labels there are left out; in task 3,
    where it is defined, the same contrary labels count and pull the figure down."""
    source = write_store(tmp_path / "goal", "libero_goal", CHEESE, [0, 1, 2, 3])
    probes = train(source, tmp_path / "probes")
    masked = write_store(tmp_path / "masked", "libero_object", CHEESE, [4, 5], contrary=(5,))
    counted = write_store(tmp_path / "counted", "libero_object", CHEESE, [4, 3], contrary=(3,))
    a = cross_suite(CrossSuiteConfig(probes=probes, store=masked, bootstrap=50)).heads["action"]
    b = cross_suite(CrossSuiteConfig(probes=probes, store=counted, bootstrap=50)).heads["action"]
    assert a.masked_rows == 3 * STEPS and b.masked_rows == 0
    best_a = a.balanced_accuracy[a.layers.index(a.best_layer)].value
    best_b = b.balanced_accuracy[b.layers.index(b.best_layer)].value
    assert best_a is not None and best_b is not None and best_a > 0.9 and best_b < 0.6


def test_command_writes_the_versioned_file_and_prints_the_table(
    spatial: Path, goal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from vlaprobe.cli import main

    out = tmp_path / "x.json"
    args = ["cross-suite", "--probes", str(spatial), "--store", str(goal), "--bootstrap", "20"]
    assert main([*args, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "(libero_spatial) on store" in text and "majority 0.500" in text and f"written to {out}" in text
    saved = read_cross_suite(out)
    assert saved.heads["object"].atoms == BOTH["object"] and saved.resamples == 20
    assert json.loads(out.read_text())["format_version"] == 2
    out.write_text(json.dumps({"format": "vlaprobe-cross-suite", "format_version": 9}))
    with pytest.raises(VlaprobeError, match="format version 9"):
        read_cross_suite(out)


def test_refusals_are_one_line(
    spatial: Path, goal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["cross-suite", "--probes", str(spatial), "--store"]
    own = str(spatial.parent / "activations")
    assert "both libero_spatial" in one_line_error(capsys, [*base, own])
    other_atoms = {"object": ["on-table(wine_rack_1)"], "action": ["grasped(wine_bottle_1)"]}
    disjoint = write_store(tmp_path / "d", "libero_goal", other_atoms, [0])
    assert "no atom probed" in one_line_error(capsys, [*base, str(disjoint)])
    other = write_store(tmp_path / "o", "libero_goal", GOAL, [0], model_id="other")
    assert "observed by model 'other'" in one_line_error(capsys, [*base, str(other)])
    wide = write_store(tmp_path / "w", "libero_goal", GOAL, [0], hidden=2 * HIDDEN)
    assert "hidden states of size 32" in one_line_error(capsys, [*base, str(wide)])
    err = one_line_error(capsys, [*base, str(goal), "--source-store", str(tmp_path / "none")])
    assert "--source-store" in err
    assert "--source-store" in one_line_error(capsys, [*base, str(goal), "--source-store", str(goal)])
    assert "at least 10" in one_line_error(capsys, [*base, str(goal), "--bootstrap", "5"])
