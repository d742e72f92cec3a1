"""`vlaprobe compare-stores` on hand-made stores whose baselines are known exactly, and its report section."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from tests.collection.test_store import make_episode, make_meta

from vlaprobe.cli import main
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.configs.stores import CompareStoresConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta, write_probes_meta
from vlaprobe.probes.store_compare import compare_stores, read_store_comparison
from vlaprobe.reports.page import _environment
from vlaprobe.reports.sections import store_comparison_section

LENGTH = 20  # two rows per decile of episode time
Atoms = Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _store(path: Path, atoms: Atoms) -> Path:
    """3 tasks x 5 episodes of LENGTH rows; atom 0 of each head from ``atoms(task, step)``, the rest false."""
    with StoreWriter.open(path, make_meta()) as w:
        for task in range(3):
            for init in range(5):
                info, arrays = make_episode(task, init, LENGTH)
                step = np.arange(LENGTH)
                obj, act = atoms(task, step)
                arrays["object_atoms"] = np.zeros_like(arrays["object_atoms"])
                arrays["object_atoms"][:, 0] = obj
                arrays["action_atoms"] = np.zeros_like(arrays["action_atoms"])
                arrays["action_atoms"][:, 0] = act
                w.write_episode(info, arrays, {"instruction": f"task {task}"})
    return path


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("stores")
    # Timed: the object atom turns true half-way through every episode (the task x time cell tells it); the
    # action atom is true in task 0 only (the task tells it).
    timed = _store(root / "timed", lambda task, step: (step >= LENGTH // 2, np.full(len(step), task == 0)))
    # Parity: both atoms true on odd rows; every task x time cell holds as many true rows as false ones in
    # every episode, so whatever a cell predicts, balanced accuracy is exactly 0.5.
    parity = _store(root / "parity", lambda task, step: (step % 2 == 1, step % 2 == 1))
    return timed, parity


def test_known_baselines_and_differences(stores: tuple[Path, Path]) -> None:
    timed, parity = stores
    c = compare_stores(CompareStoresConfig(stores=(timed, parity), names=("timed", "parity"), bootstrap=50))
    a, b = c.stores
    assert (a.name, a.episodes, a.rows, a.test_episodes, a.perturbed_episodes) == ("timed", 15, 300, 3, 0)
    obj, act = a.heads["object"], a.heads["action"]
    assert (obj.kept, obj.distinct_states, obj.varying_atoms) == (1, 2, 1)
    assert obj.baselines["majority"].value == 0.5 and obj.baselines["task"].value == 0.5
    assert obj.baselines["task_time"].value == 1.0
    assert (obj.baselines["task_time"].low, obj.baselines["task_time"].high) == (1.0, 1.0)
    assert (act.kept, act.varying_atoms) == (1, 0)  # constant within every episode
    assert act.baselines["task"].value == 1.0 and act.baselines["task_time"].value == 1.0
    assert a.heads["object"].difference is None
    for head in ("object", "action"):
        h = b.heads[head]
        assert (h.kept, h.distinct_states, h.varying_atoms) == (1, 2, 1)
        assert all(h.baselines[name].value == 0.5 for name in ("majority", "task", "task_time"))
        assert h.difference is not None
    diff = b.heads["object"].difference["task_time"]  # type: ignore[index]
    assert (diff.value, diff.low, diff.high) == (-0.5, -0.5, -0.5)
    assert b.heads["action"].difference["task"].value == -0.5  # type: ignore[index]


def test_command_writes_the_report_section(
    stores: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    probes = tmp_path / "probes"
    head = HeadMeta(kept=["on(a,b)"], best_layer=0)
    write_probes_meta(probes, ProbesMeta("m", "last_prompt", 4, 1, [0], 0.5, {"object": head}))
    args = ["compare-stores", *map(str, stores), "--names", "fixed", "sampled", "--bootstrap", "20"]
    assert main([*args, "--probes", str(probes)]) == 0
    out = capsys.readouterr().out
    assert "fixed:" in out and "minus fixed: majority +0.000" in out and "task_time -0.500" in out
    saved = read_store_comparison(probes)
    assert [s.name for s in saved.stores] == ["fixed", "sampled"]
    section = store_comparison_section(probes)
    assert section is not None and section.template == "store_comparison.html"
    html = _environment().get_template(section.template).render(section=section, data=section.data)
    assert 'id="stores-section"' in html and "-0.500 [-0.500, -0.500]" in html


def test_bad_input(stores: tuple[Path, Path], tmp_path: Path) -> None:
    timed, _ = stores
    with pytest.raises(VlaprobeError, match="at least 2 stores"):
        compare_stores(CompareStoresConfig(stores=(timed,)))
    with pytest.raises(VlaprobeError, match="one per store"):
        compare_stores(CompareStoresConfig(stores=(timed, timed), names=("a",)))
    with pytest.raises(VlaprobeError, match="not an activation store"):
        compare_stores(CompareStoresConfig(stores=(timed, tmp_path)))
    assert main(["compare-stores", str(timed), str(timed), "--probes", str(tmp_path)]) == 2
    for flags in (
        ["--seed", "-1"],
        ["--test-fraction", "-0"],
        ["--test-fraction", "nan"],
    ):  # the fuzzer's finds
        assert main(["compare-stores", str(timed), str(stores[1]), *flags]) == 2
    with pytest.raises(VlaprobeError, match="given twice: it would be compared with itself"):
        compare_stores(
            CompareStoresConfig(stores=(timed, timed.parent / ".." / timed.parent.name / timed.name))
        )
