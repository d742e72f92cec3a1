"""The live server's readout equals the offline readout bit for bit, on probes the real training code wrote."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from vlaprobe.cognition.readout import ProbeReadout
from vlaprobe.configs.train import ProbeConfig, TrainConfig
from vlaprobe.live.serve import ProbeReading
from vlaprobe.probes import ProbeSet, synthetic_data, train_on_data
from vlaprobe.probes.apply import apply_probes_to_rows
from vlaprobe.probes.probemeta import read_probes_meta, write_probes_meta

HEADS = ("object", "action")


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    data = synthetic_data(
        num_tasks=2, episodes_per_task=3, steps_per_episode=12, num_layers=4, hidden_size=16, num_object=8,
        num_action=3, signal=6.0, seed=3,
    )  # fmt: skip
    cfg = TrainConfig(
        bootstrap=10, auprc_bootstrap=0, shuffled_control=False, probe=ProbeConfig(c_grid=(0.1, 1.0))
    )
    out = train_on_data(data, cfg, tmp_path_factory.mktemp("parity") / "probes")
    return out, data.hidden.float().numpy()  # (layers, steps, hidden)


def test_live_readout_equals_the_probe_set_bit_for_bit(trained: tuple[Path, np.ndarray]) -> None:
    folder, hidden = trained
    probes = ProbeSet.load(folder)
    assert probes.meta.standardized and all(f"{h}.mean" in probes.tensors for h in HEADS)
    live = ProbeReading(probes)  # what `vlaprobe serve` builds (build_engine) and StepBuilder.step reads
    assert live.layers == {h: probes.default_layer(h) for h in HEADS}
    for t in range(hidden.shape[1]):
        step = hidden[:, t]  # every hidden state of one step, as the policy hands it to the live loop
        reading = live.read(step)
        for h in HEADS:
            kept = np.flatnonzero(reading[h].probed)
            offline = torch.sigmoid(probes.logits(step, h))
            assert torch.equal(torch.from_numpy(reading[h].probs[kept]), offline)
            predicted = probes.predict(step, head=h)
            assert [int(v) for v in reading[h].values[kept]] == [predicted[a] for a in probes.atoms(h)]


def test_monitor_rows_equal_live_steps_and_the_evaluation_path(trained: tuple[Path, np.ndarray]) -> None:
    """``vlaprobe monitor`` reads a stored episode's rows (assign_steps) exactly as the live server reads steps;
    the batched path of training's evaluation and ``vlaprobe hypotheses`` agrees with it to float rounding."""
    folder, hidden = trained
    readout = ProbeReadout.load(folder)
    rows = {h: hidden[readout.layers[h]] for h in HEADS}
    batch = readout.assign_steps(rows)
    probes = readout.probes
    for t in range(hidden.shape[1]):
        one = readout.assign(hidden[:, t])
        for h in HEADS:
            assert np.array_equal(batch.probs[h][t], one.probs[h], equal_nan=True)  # NaN: not probed
            assert np.array_equal(batch.values[h][t], one.values[h])
    for h in HEADS:
        i = probes.layers.index(readout.layers[h])
        tensors = [probes.tensors.get(f"{h}.{n}") for n in ("weight", "bias", "mean", "std")]
        logits = apply_probes_to_rows(torch.from_numpy(hidden), *tensors)[i]  # type: ignore[arg-type]
        kept = np.flatnonzero(readout.probed[h])
        assert torch.allclose(torch.sigmoid(logits), torch.from_numpy(batch.probs[h][:, kept]), atol=1e-6)


def test_no_layer_given_reads_the_earliest_layer_tied_with_the_best(
    trained: tuple[Path, np.ndarray], tmp_path: Path
) -> None:
    folder, hidden = trained
    meta = read_probes_meta(folder)
    head = meta.heads["object"]
    assert head.tied_layers[0] == head.default_layer == min(head.tied_layers)
    assert head.best_layer in head.tied_layers
    head.tied_layers, head.default_layer = sorted({1, 2, head.best_layer}), 1
    for f in folder.iterdir():
        (tmp_path / f.name).write_bytes(f.read_bytes())
    write_probes_meta(tmp_path, meta)
    probes = ProbeSet.load(tmp_path)
    assert probes.default_layer("object") == 1 and ProbeReading(probes).layers["object"] == 1
    step = hidden[:, 0]
    assert torch.equal(probes.logits(step, "object"), probes.logits(step, "object", layer=1))
