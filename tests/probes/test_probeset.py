"""Saved probes: safetensors + JSON round trip, live prediction, refusal of foreign models and damaged folders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta
from vlaprobe.probes.probeset import META_FILE, WEIGHTS_FILE, ProbeSet


def make_probes(standardized: bool = False) -> ProbeSet:
    g = torch.Generator().manual_seed(0)
    layers, hidden = [0, 1, 2], 8
    tensors = {
        "object.weight": torch.randn(3, hidden, 2, generator=g),
        "object.bias": torch.randn(3, 2, generator=g),
        "action.weight": torch.randn(3, hidden, 1, generator=g),
        "action.bias": torch.randn(3, 1, generator=g),
    }
    if standardized:
        for h in ("object", "action"):
            tensors[f"{h}.mean"] = torch.randn(3, hidden, generator=g)
            tensors[f"{h}.std"] = torch.rand(3, hidden, generator=g) + 0.5
    meta = ProbesMeta(
        model_id="tiny-openvla",
        pooling="last_prompt",
        hidden_size=hidden,
        num_hidden_states=3,
        layers=layers,
        threshold=0.5,
        heads={
            "object": HeadMeta(kept=["on(a,b)", "open(c)"], best_layer=2, best_metric="accuracy"),
            "action": HeadMeta(kept=["grasped(a)"], best_layer=1, best_metric="accuracy"),
        },
    )
    return ProbeSet(meta, tensors)


@pytest.mark.parametrize("standardized", [False, True])
def test_round_trip_and_prediction_match_the_weights(tmp_path: Path, standardized: bool) -> None:
    probes = make_probes(standardized)
    probes.save(tmp_path)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp files left
    loaded = ProbeSet.load(tmp_path, model_id="tiny-openvla", pooling="last_prompt")
    hidden = torch.randn(3, 8)
    probs = loaded.probabilities(hidden)
    assert list(probs) == ["on(a,b)", "open(c)", "grasped(a)"]
    for head, layer in (("object", 2), ("action", 1)):  # each head at its own best layer
        x = hidden[layer]
        if standardized:
            x = (x - probes.tensors[f"{head}.mean"][layer]) / probes.tensors[f"{head}.std"][layer]
        expected = torch.sigmoid(
            x @ probes.tensors[f"{head}.weight"][layer] + probes.tensors[f"{head}.bias"][layer]
        )
        got = [probs[a] for a in probes.atoms(head)]
        assert got == pytest.approx(expected.tolist(), abs=1e-6)
    pred = loaded.predict(hidden.numpy())
    assert pred == {a: int(p > 0.5) for a, p in probs.items()}
    # one hidden state at an explicit layer gives the same as picking that row
    assert loaded.predict(hidden[0], layer=0) == loaded.predict(hidden, layer=0)


def test_single_hidden_state_needs_a_layer_when_default_layers_differ(tmp_path: Path) -> None:
    probes = make_probes()
    with pytest.raises(VlaprobeError, match="default layers differ"):
        probes.predict(torch.randn(8))
    assert set(probes.predict(torch.randn(8), head="action")) == {"grasped(a)"}


def test_wrong_shapes_are_refused() -> None:
    probes = make_probes()
    with pytest.raises(VlaprobeError, match="hidden size 8"):
        probes.predict(np.zeros(5), layer=0)
    with pytest.raises(VlaprobeError, match="do not fit"):
        probes.predict(np.zeros((4, 8)))
    with pytest.raises(VlaprobeError, match="no probe for hidden state 7"):
        probes.predict(np.zeros(8), layer=7)


def test_probes_of_another_model_or_pooling_are_refused(tmp_path: Path) -> None:
    make_probes().save(tmp_path)
    with pytest.raises(VlaprobeError, match="trained on model 'tiny-openvla', not 'openvla-7b'") as err:
        ProbeSet.load(tmp_path, model_id="openvla-7b")
    assert "\n" not in str(err.value)
    with pytest.raises(VlaprobeError, match="pooling"):
        ProbeSet.load(tmp_path, pooling="action_tokens")


def test_not_a_probe_folder_and_damaged_files(tmp_path: Path) -> None:
    with pytest.raises(VlaprobeError, match="not a probe folder"):
        ProbeSet.load(tmp_path)
    make_probes().save(tmp_path)
    meta = json.loads((tmp_path / META_FILE).read_text())
    meta["format_version"] = 99
    (tmp_path / META_FILE).write_text(json.dumps(meta))
    with pytest.raises(VlaprobeError, match="version 99"):
        ProbeSet.load(tmp_path)
    make_probes().save(tmp_path)
    (tmp_path / WEIGHTS_FILE).write_bytes(b"garbage")
    with pytest.raises(VlaprobeError, match="cannot read"):
        ProbeSet.load(tmp_path)


def test_action_tokens_pooling_averages_the_token_positions() -> None:
    probes = make_probes()
    probes.meta.pooling = "action_tokens"
    tokens = torch.randn(3, 7, 8)
    assert probes.probabilities(tokens) == probes.probabilities(tokens.mean(1))
