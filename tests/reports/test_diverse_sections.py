"""`vlaprobe hypotheses` on a trained probe folder, and the report's H1/H2 and diversity sections."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.collection.test_store import write

from vlaprobe.cli import main
from vlaprobe.configs.hypotheses import HypothesesConfig
from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.train import ProbeConfig, TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes import train as train_module
from vlaprobe.probes.hypotheses_run import hypotheses, read_hypotheses
from vlaprobe.probes.results import read_evaluation
from vlaprobe.probes.ties import describe
from vlaprobe.reports.report import write_report


@pytest.fixture(scope="module")
def probes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("run")
    store = root / "activations"
    write(store, [(t, i, 6 + (t + i) % 3) for t in range(3) for i in range(3)])
    out = root / "probes"
    train_module.train_probes(
        TrainConfig(
            store=store,
            out=out,
            bootstrap=20,
            auprc_bootstrap=0,
            shuffled_permutations=1,
            probe=ProbeConfig(c_grid=(0.1,), max_iter=50),
        )
    )
    return out


def test_hypotheses_file_and_report_sections(probes: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["hypotheses", "--probes", str(probes), "--bootstrap", "50"]) == 0
    printed = capsys.readouterr().out
    assert "H1 (object states are encoded in earlier layers" in printed and "H2 (" in printed
    for head, h in read_evaluation(probes).heads.items():  # the layers tied with the best, named
        assert f"evaluation.json: {describe(h.best.layer, h.best.tied)}" in printed, head
    saved = read_hypotheses(probes)
    assert saved.resamples == 50 and set(saved.heads) == {"object", "action"}
    assert [v.hypothesis for v in saved.verdicts] == ["H1", "H2"]
    again = hypotheses(HypothesesConfig(probes=probes, bootstrap=50))  # same seed: same answer
    assert again == saved
    page = write_report(ReportConfig(probes=probes, out=probes.parent / "report")).read_text()
    assert 'id="hypotheses-section"' in page and "H1</strong>" in page
    assert 'id="diversity-section"' in page and "distinct state vectors" in page


def test_hypotheses_refuses_bad_input(probes: Path) -> None:
    with pytest.raises(VlaprobeError, match="--bootstrap must be at least 10"):
        hypotheses(HypothesesConfig(probes=probes, bootstrap=2))
    with pytest.raises(
        VlaprobeError, match=r"no evaluation\.json in .*; pass the folder written by vlaprobe train"
    ):
        hypotheses(HypothesesConfig(probes=probes.parent / "none"))
