"""The report's matched-steps section, from a probe folder written by vlaprobe train's real writer."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch

from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.train import TrainConfig
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.results import read_evaluation
from vlaprobe.reports.report import write_report


def test_the_report_shows_the_matched_steps_per_family(tmp_path: Path) -> None:
    data = synthetic_data(
        num_tasks=2, episodes_per_task=4, steps_per_episode=20, num_layers=2, hidden_size=16
    )
    noise = torch.randn(data.hidden.shape, generator=torch.Generator().manual_seed(0)).to(data.hidden.dtype)
    control = dataclasses.replace(data, hidden=noise, model_id="untrained")
    cfg = TrainConfig(bootstrap=50, auprc_bootstrap=0, shuffled_control=False, conditional=True)
    probes = train_on_data(data, cfg, tmp_path / "probes", observer=control)
    page = write_report(ReportConfig(probes=probes, dpi=40)).read_text()
    assert 'id="matched-section"' in page and "observer control (untrained)" in page
    tables = json.loads((probes.parent / "report" / "matched.json").read_text())
    evaluation = read_evaluation(probes)
    for head, h in evaluation.heads.items():
        rows = tables["heads"][head]["rows"]
        assert [r["family"] for r in rows] == ["all atoms", *h.families]
        assert rows[0]["probe"]["value"] == h.matched.probe.layer.value[h.best.index]  # type: ignore[union-attr]
        assert f"<td>{rows[1]['family']}</td>" in page
