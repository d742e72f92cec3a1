"""`vlaprobe report` output: every figure as PNG, SVG, CSV and JSON, and a self-contained HTML page."""

from __future__ import annotations

import csv
import dataclasses
import json
import re
from pathlib import Path

import markupsafe
import numpy as np
import pytest
import torch

from vlaprobe.configs.report import ReportConfig
from vlaprobe.configs.train import TrainConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import OWNER_FILE
from vlaprobe.probes import synthetic_data, train_on_data
from vlaprobe.probes.results import FORMAT_VERSION
from vlaprobe.probes.ties import describe
from vlaprobe.reports import write_report

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("run")
    data = synthetic_data(
        num_tasks=3,
        episodes_per_task=4,
        steps_per_episode=25,
        num_layers=4,
        hidden_size=32,
        num_object=27,
        num_action=4,
        signal=8.0,
        seed=2,
    )
    # Make one predicate ("open") constant so that its whole column must be skipped.
    names = data.atom_names["object"]
    labels = dict(data.labels)
    labels["object"] = labels["object"].copy()
    labels["object"][:, [i for i, a in enumerate(names) if a.startswith("open(")]] = False
    noise = torch.randn(data.hidden.shape, generator=torch.Generator().manual_seed(0)).half()
    data = dataclasses.replace(data, labels=labels)
    observer = dataclasses.replace(data, hidden=noise, model_id="random-init")
    probes = train_on_data(
        data,
        TrainConfig(bootstrap=100, auprc_bootstrap=10, conditional=True),
        root / "probes",
        observer=observer,
    )
    page = write_report(ReportConfig(probes=probes, dpi=60))
    return {
        "page": page,
        "dir": page.parent,
        "probes": probes,
        "ev": json.loads((probes / "evaluation.json").read_text()),
    }


def test_default_location_and_files(report: dict) -> None:
    assert report["dir"] == report["probes"].parent / "report"
    names = {p.name for p in report["dir"].iterdir()}
    for stem in (
        "heatmap_accuracy",
        "heatmap_selectivity",
        "heatmap_observer_accuracy",
        "curves_object",
        "curves_action",
    ):
        assert {f"{stem}.{ext}" for ext in ("png", "svg", "csv", "json")} <= names, stem
    assert {"index.html", "tables.json"} <= names
    assert not [n for n in names if n.startswith(".") and n != OWNER_FILE]  # no temp files left


def test_images_have_valid_headers(report: dict) -> None:
    for path in report["dir"].glob("*.png"):
        assert path.read_bytes()[:8] == PNG, path
    for path in report["dir"].glob("*.svg"):
        head = path.read_text()[:400]
        assert "<svg" in head and "xmlns" in head, path


def test_heatmap_data_follows_the_paper_column_order(report: dict) -> None:
    data = json.loads((report["dir"] / "heatmap_accuracy.json").read_text())
    columns = data["columns"]
    order = [
        "behind",
        "in-front-of",
        "left-of",
        "right-of",
        "on",
        "on-table",
        "inside",
        "open",
        "turned-on",
        "grasped",
        "should-move-towards",
    ]
    preds = [c.split(": ")[1] for c in columns]
    assert preds == sorted(preds, key=order.index)
    assert [c.split(": ")[0] for c in columns] == sorted(
        (c.split(": ")[0] for c in columns), key=["object", "action"].index
    )
    assert "open" not in preds and "open" in report["ev"]["heads"]["object"]["skipped_predicates"]
    values = np.array(data["values"], float)
    assert values.shape == (len(data["layers"]), len(columns))
    # the heatmap equals the per-predicate figures of evaluation.json
    obj = report["ev"]["heads"]["object"]
    j = obj["predicates"].index(preds[0])
    np.testing.assert_allclose(
        values[:, 0], np.array(obj["probe"]["accuracy"]["predicate"]["value"], float)[:, j], rtol=0, atol=5e-6
    )  # the figures' data keep 5 decimals


def test_csv_files_parse_and_match_the_json(report: dict) -> None:
    with open(report["dir"] / "heatmap_accuracy.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    data = json.loads((report["dir"] / "heatmap_accuracy.json").read_text())
    assert len(rows) == len(data["layers"]) * len(data["columns"])
    assert {"head", "predicate", "layer", "value", "ci_low", "ci_high", "majority_baseline"} <= set(rows[0])
    for r in rows:
        if r["value"] and r["ci_low"]:
            assert float(r["ci_low"]) <= float(r["value"]) + 1e-9 <= float(r["ci_high"]) + 2e-9
    with open(report["dir"] / "curves_object.csv", newline="") as f:
        curve_rows = list(csv.DictReader(f))
    series = {r["series"] for r in curve_rows}
    assert series == {
        "probe",
        "majority baseline",
        "time baseline",
        "task baseline",
        "task × time baseline",
        "shuffled-label control",
        "observer control",
    }
    assert {r["metric"] for r in curve_rows} == {"accuracy", "balanced_accuracy", "f1", "auprc"}


def test_html_is_self_contained_with_every_section(report: dict) -> None:
    text = report["page"].read_text()
    for section in (
        "Data and split",
        "Dataset size",
        "Best layers and baselines",
        "majority baseline",
        "shuffled control",
        "selectivity",
        "Dropped atoms",
        "Figures",
        "Configuration",
        "random-init",
    ):
        assert section in text, section
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", text)
    assert len(images) == 5
    assert "<img" in text and "src='http" not in text and "<script" not in text
    dropped = report["ev"]["heads"]["object"]["dropped"]
    assert dropped and all(d["atom"] in text for d in dropped)


def test_missing_or_foreign_folder_is_a_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(VlaprobeError, match=r"no evaluation\.json"):
        write_report(ReportConfig(probes=tmp_path))
    (tmp_path / "evaluation.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(VlaprobeError, match="not a vlaprobe evaluation"):
        write_report(ReportConfig(probes=tmp_path))


def test_extra_sections_render_from_their_template(report: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    from vlaprobe.reports import sections
    from vlaprobe.reports.sections import Section

    template = Path(sections.__file__).parent / "templates" / "test_extra_section.html"
    template.write_text("<p class='extra'>{{ data.answer }} {{ section.title }}</p>\n")
    try:
        monkeypatch.setattr(
            sections,
            "SECTION_PROVIDERS",
            ["tests.reports.test_report:_provider"],
        )
        extra = Section("mine", "My section", "test_extra_section.html", {"answer": "<42>"})
        page = write_report(ReportConfig(probes=report["probes"], out=report["dir"] / "x", dpi=40), [extra])
        text = page.read_text()
    finally:
        template.unlink()
    assert "<h2 id='mine'>My section</h2>" in text and "<p class='extra'>&lt;42&gt; My section</p>" in text
    assert "<h2 id='found'>Found</h2>" in text and text.index("id='mine'") < text.index("id='config'")


def _provider(probes: Path) -> object:
    from vlaprobe.reports.sections import Section

    return Section("found", "Found", "test_extra_section.html", {"answer": probes.name})


def test_page_shows_resamples_realized_split_and_control_spread(report: dict) -> None:
    text = report["page"].read_text()
    ev = report["ev"]
    assert ev["format_version"] == FORMAT_VERSION and ev["controls"]["shuffled_permutations"] == 5
    assert "resamples defining balanced accuracy" in text and "5 permutations" in text
    split = ev["split"]
    assert split["realized_test_fraction"] == pytest.approx(3 / 12) and split["test_fraction"] == 0.2
    assert "held out: 25.0% of the episodes; requested 20.0%" in text
    tables = json.loads((report["dir"] / "tables.json").read_text())
    row = tables["object"]["best_layer"]["rows"][-1]
    assert 0 < row["probe.balanced_accuracy.defined"] <= 100 and row["control.accuracy.sd"] >= 0


def test_baselines_that_know_the_task_are_in_the_tables_and_the_headline(report: dict) -> None:
    text = report["page"].read_text()
    tables = json.loads((report["dir"] / "tables.json").read_text())
    for head, t in tables.items():
        h = report["ev"]["heads"][head]
        row = t["best_layer"]["rows"][-1]  # (all atoms)
        tt = h["task_time_baseline"]["balanced_accuracy"]["layer"]["value"][0]
        assert row["task_time_baseline.balanced_accuracy"] == tt
        best = h["best"]["index"]
        sel = h["selectivity_task_time"]["balanced_accuracy"]["layer"]
        assert row["selectivity_task_time.balanced_accuracy"] == sel["value"][best]
        low, high = sel["low"][best], sel["high"][best]
        verdict = "beats it" if low > 0 else "is below it" if high < 0 else "does not beat it"
        assert (
            t["headline"].startswith(f"{head}: best layer {h['best']['layer']}") and verdict in t["headline"]
        )
        assert t["headline"].replace("×", "&#215;") in text or t["headline"] in text
    assert "selectivity over the task × time baseline" in text and "task baseline (bal.)" in text


def test_headline_table_and_heatmap_name_the_layers_tied_with_the_best(report: dict) -> None:
    text = report["page"].read_text()
    tables = json.loads((report["dir"] / "tables.json").read_text())
    heat = json.loads((report["dir"] / "heatmap_accuracy.json").read_text())
    for head, t in tables.items():
        best = report["ev"]["heads"][head]["best"]
        assert best["layer"] in best["tied"] and t["best_layer"]["tied"] == best["tied"]
        others = [x for x in best["tied"] if x != best["layer"]]
        expected = describe(best["layer"], best["tied"])
        assert t["headline"].startswith(f"{head}: {expected};") and t["best_layer"]["tied_text"] == expected
        assert ("tied with" in expected) == bool(others) and expected in text
        assert heat["tied"][head] == best["tied"] and heat["best"][head] == best["layer"]
    assert "the layers tied with its best layer" in text


def test_conditional_probing_has_its_section_and_a_headline_per_head(report: dict) -> None:
    text = report["page"].read_text()
    tables = json.loads((report["dir"] / "tables.json").read_text())
    section = json.loads((report["dir"] / "conditional.json").read_text())
    assert "What the hidden states add beyond task and time" in text and "id='conditional'" in text
    for head, t in tables.items():
        h = report["ev"]["heads"][head]
        tt = h["conditional_task_time"]
        beyond = [i for i, low in enumerate(tt["gain"]["low"]) if low is not None and low > 0]
        sentence = t["conditional_headline"]
        assert sentence.startswith(f"{head}: a probe on the task × time cells alone scores")
        assert ("add information beyond it at layers" in sentence) == bool(beyond)
        assert ("no layer adds information beyond it" in sentence) == (not beyond)
        assert str(markupsafe.escape(sentence)) in text  # the page's autoescaping, as rendered
        rows = section["heads"][head]["rows"]
        assert [r["layer"] for r in rows] == report["ev"]["layers"]
        assert [r["task_time.gain"] for r in rows] == tt["gain"]["value"]
        assert [i for i, r in enumerate(rows) if r["task_time.beyond"]] == beyond
        assert {b["key"] for b in section["heads"][head]["baselines"]} == {"task", "task_time"}
