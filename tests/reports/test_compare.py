"""The observer-versus-control section: per-layer verdicts from the intervals, and the rendered page."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.train import TrainConfig
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.results import Level, MetricSummary, read_evaluation
from vlaprobe.reports import write_report
from vlaprobe.reports.compare import compare, compare_head, report_section


def _summary(values, lows, highs) -> MetricSummary:
    level = Level(value=values, low=lows, high=highs, defined=[10] * len(values))
    return MetricSummary(atom=level, predicate=level, layer=level)


def test_verdicts_follow_non_overlapping_intervals() -> None:
    observer = _summary([0.9, 0.7, 0.5, None], [0.85, 0.6, 0.45, None], [0.95, 0.8, 0.55, None])
    control = _summary([0.6, 0.65, 0.7, 0.6], [0.55, 0.55, 0.6, 0.5], [0.65, 0.75, 0.8, 0.7])
    h = compare_head("object", [0, 1, 2, 3], observer, control)
    assert [r.verdict for r in h.rows] == ["better", "", "worse", ""]
    assert h.better == [0] and h.worse == [2]
    assert h.best_observer.layer == 0 and h.best_control.layer == 2


def test_section_on_a_trained_observer_against_noise(tmp_path: Path) -> None:
    data = synthetic_data(
        num_tasks=3, episodes_per_task=4, steps_per_episode=20, num_layers=3, hidden_size=16,
        num_object=6, num_action=3, signal=8.0, seed=1,
    )  # fmt: skip
    noise = torch.randn(data.hidden.shape, generator=torch.Generator().manual_seed(0)).half()
    observer = dataclasses.replace(data, hidden=noise, model_id="noise")
    probes = train_on_data(
        data, TrainConfig(bootstrap=50, auprc_bootstrap=5), tmp_path / "probes", observer=observer
    )
    comparison = compare(read_evaluation(probes))
    assert comparison is not None and comparison.control == "noise"
    # The signal peaks in the middle layer (synthetic_data's profile); the noise has none.
    for h in comparison.heads:
        assert h.rows[1].layer in h.better and not h.worse, h
    page = write_report(ReportConfig(probes=probes, dpi=50)).read_text()
    assert (
        'id="observer-vs-control"' in page and "better than the control beyond the intervals" in page.lower()
    )


def test_no_section_without_an_observer_control(tmp_path: Path) -> None:
    data = synthetic_data(
        num_tasks=2, episodes_per_task=3, steps_per_episode=10, num_layers=2, hidden_size=8,
        num_object=4, num_action=2, signal=4.0, seed=0,
    )  # fmt: skip
    probes = train_on_data(data, TrainConfig(bootstrap=20, auprc_bootstrap=5), tmp_path / "probes")
    assert report_section(probes) is None
    assert report_section(tmp_path / "nothing") is None
