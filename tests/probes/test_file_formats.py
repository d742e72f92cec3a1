"""The probe folder's files: each has one writer and one reader; a round trip gives the same dataclass, a newer
or unknown format is refused with one line, and a file of the older format (as the project wrote it) still reads."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from tests.probes.made import evaluation_with_split

from vlaprobe.errors import VlaprobeError
from vlaprobe.probes import hypotheses_run, probemeta, results, store_compare
from vlaprobe.probes.hypotheses import LayerCurves, answer_hypotheses
from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta
from vlaprobe.probes.results import DroppedAtom
from vlaprobe.probes.store_compare import Estimate, HeadFigures, StoreComparison, StoreFigures


def probes_meta() -> ProbesMeta:
    head = HeadMeta(
        kept=["on(a,b)"],
        best_layer=3,
        best_metric="balanced_accuracy",
        atom_names=["on(a,b)", "on(b,a)"],
        kept_index=[0],
        dropped=[DroppedAtom("on(b,a)", 0.0, "never true in training")],
        best_value=0.9,
        best_rule="highest value",
        tied_layers=[2, 3],
        default_layer=2,
    )
    return ProbesMeta("m", "last_prompt", 8, 5, [1, 2, 3], 0.5, {"object": head}, config={"store": "runs/s"})


def hypotheses() -> object:
    rng = np.random.default_rng(0)
    layers = (0, 1, 2, 3)
    point = {"object": np.array([0.6, 0.9, 0.8, 0.7]), "action": np.array([0.5, 0.6, 0.7, 0.9])}
    resamples = {h: p + rng.normal(0, 0.02, (30, 4)) for h, p in point.items()}
    return answer_hypotheses(LayerCurves(layers, point, resamples, episodes=10))


def comparison() -> StoreComparison:
    e = Estimate(0.7, 0.6, 0.8)
    head = HeadFigures(5, 3, 4, 2, {"majority": e, "task": e, "task_time": e}, None)
    store = StoreFigures("fixed", "runs/s", 10, 200, 3, 0, {"object": head})
    return StoreComparison("balanced_accuracy", 0, 0.3, 20, [store])


@dataclass(frozen=True)
class Format:
    file: str
    make: Callable[[], object]
    write: Callable[[Path, object], object]
    read: Callable[[Path], object]
    version: int
    versioned_since: int
    """The first version that recorded ``format_version``; older files lack it and read as this version."""


FORMATS = {
    "probes": Format(
        probemeta.META_FILE,
        probes_meta,
        probemeta.write_probes_meta,  # type: ignore[arg-type]
        probemeta.read_probes_meta,
        probemeta.FORMAT_VERSION,
        1,
    ),
    "evaluation": Format(
        results.EVALUATION_FILE,
        lambda: evaluation_with_split(["t00_i00_a00"]),
        results.write_evaluation,  # type: ignore[arg-type]
        results.read_evaluation,
        results.FORMAT_VERSION,
        1,
    ),
    "hypotheses": Format(
        hypotheses_run.FILE,
        hypotheses,
        hypotheses_run.write_hypotheses,  # type: ignore[arg-type]
        hypotheses_run.read_hypotheses,
        hypotheses_run.FORMAT_VERSION,
        2,
    ),
    "store_comparison": Format(
        store_compare.FILE,
        comparison,
        store_compare.write_store_comparison,  # type: ignore[arg-type]
        store_compare.read_store_comparison,
        store_compare.FORMAT_VERSION,
        2,
    ),
}


def _edit(path: Path, change: Callable[[dict], None]) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _one_line(read: Callable[[Path], object], folder: Path, match: str) -> None:
    with pytest.raises(VlaprobeError, match=match) as exc:
        read(folder)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("name", list(FORMATS))
def test_round_trip(name: str, tmp_path: Path) -> None:
    f = FORMATS[name]
    value = f.make()
    f.write(tmp_path, value)
    assert f.read(tmp_path) == value
    saved = json.loads((tmp_path / f.file).read_text())
    assert saved["format_version"] == f.version and saved["format"].startswith("vlaprobe-")


@pytest.mark.parametrize("name", list(FORMATS))
def test_a_newer_version_is_refused_with_one_line(name: str, tmp_path: Path) -> None:
    f = FORMATS[name]
    f.write(tmp_path, f.make())
    _edit(tmp_path / f.file, lambda d: d.update(format_version=f.version + 1))
    _one_line(f.read, tmp_path, f"version {f.version + 1}")


@pytest.mark.parametrize("name", list(FORMATS))
def test_an_unknown_format_or_a_damaged_file_is_refused_with_one_line(name: str, tmp_path: Path) -> None:
    f = FORMATS[name]
    f.write(tmp_path, f.make())
    _edit(tmp_path / f.file, lambda d: d.update(format="something-else"))
    _one_line(f.read, tmp_path, "not a vlaprobe")
    f.write(tmp_path, f.make())
    _edit(tmp_path / f.file, lambda d: d.update(format_version="x"))
    _one_line(f.read, tmp_path, "version x")
    (tmp_path / f.file).write_text("{")
    _one_line(f.read, tmp_path, "cannot read")
    (tmp_path / f.file).unlink()
    _one_line(f.read, tmp_path, str(f.file))  # missing: "no <file> ..."


@pytest.mark.parametrize("name", ["hypotheses", "store_comparison"])
def test_a_file_written_before_format_versions_still_reads(name: str, tmp_path: Path) -> None:
    f = FORMATS[name]
    value = f.make()
    f.write(tmp_path, value)

    def strip(d: dict) -> None:
        del d["format"], d["format_version"]

    _edit(tmp_path / f.file, strip)
    assert f.read(tmp_path) == value


def test_a_version_1_probes_file_reads_with_the_best_layer_as_its_tie_set(tmp_path: Path) -> None:
    probemeta.write_probes_meta(tmp_path, probes_meta())

    def to_version_1(d: dict) -> None:  # what `vlaprobe train` wrote before tied layers existed
        d["format_version"] = 1
        for head in d["heads"].values():
            del head["tied_layers"], head["default_layer"]

    _edit(tmp_path / probemeta.META_FILE, to_version_1)
    head = probemeta.read_probes_meta(tmp_path).heads["object"]
    assert (head.best_layer, head.tied_layers, head.default_layer) == (3, [3], 3)
    assert probemeta.read_probes_meta(tmp_path).store == Path("runs/s")


def test_the_probe_sets_layers_come_from_the_file(tmp_path: Path) -> None:
    meta = probes_meta()
    probemeta.write_probes_meta(tmp_path, meta)
    read = probemeta.read_probes_meta(tmp_path)
    assert read.heads["object"].default_layer == min(read.heads["object"].tied_layers) == 2
    assert HeadMeta(kept=["x"], best_layer=4).tied_layers == [4]  # no ties recorded: the best layer alone
