"""ProbeReadout: probes + hidden states -> a full assignment; equal to ProbeSet's predictions, majority elsewhere."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from vlaprobe.cognition import ProbeReadout
from vlaprobe.errors import VlaprobeError
from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta
from vlaprobe.probes.probeset import ProbeSet
from vlaprobe.probes.results import DroppedAtom

LAYERS, HIDDEN = 3, 16
NAMES = {"object": [f"on(o{i},t)" for i in range(6)], "action": ["grasped(o0)", "grasped(o1)", "grasped(o2)"]}
KEPT = {"object": [0, 2, 3, 5], "action": [1]}
FREQ = {"object": {1: 0.9, 4: 0.01}, "action": {0: 0.002, 2: 0.7}}


def probe_set(pooling: str = "last_prompt", standardized: bool = True, without: str = "") -> ProbeSet:
    rng = np.random.default_rng(0)
    heads, tensors = {}, {}
    for h, names in NAMES.items():
        if h == without:
            continue
        kept = KEPT[h]
        heads[h] = HeadMeta(
            atom_names=names,
            kept=[names[j] for j in kept],
            kept_index=kept,
            dropped=[DroppedAtom(names[j], f, "constant") for j, f in FREQ[h].items()],
            best_layer=1 if h == "object" else 2,
        )
        tensors[f"{h}.weight"] = torch.tensor(
            rng.standard_normal((LAYERS, HIDDEN, len(kept))), dtype=torch.float32
        )
        tensors[f"{h}.bias"] = torch.tensor(rng.standard_normal((LAYERS, len(kept))), dtype=torch.float32)
        if standardized:
            tensors[f"{h}.mean"] = torch.tensor(rng.standard_normal((LAYERS, HIDDEN)), dtype=torch.float32)
            tensors[f"{h}.std"] = torch.tensor(rng.random((LAYERS, HIDDEN)) + 0.5, dtype=torch.float32)
    meta = ProbesMeta(
        model_id="m",
        pooling=pooling,
        hidden_size=HIDDEN,
        num_hidden_states=LAYERS,
        layers=list(range(LAYERS)),
        threshold=0.5,
        heads=heads,
    )
    return ProbeSet(meta, tensors)


@pytest.mark.parametrize("standardized", [True, False])
def test_assignment_matches_the_probes_and_holds_dropped_atoms_at_the_majority(standardized: bool) -> None:
    probes = probe_set(standardized=standardized)
    readout = ProbeReadout(probes)
    hidden = np.random.default_rng(1).standard_normal((LAYERS, HIDDEN)).astype(np.float16)
    a = readout.assign(hidden)
    expected = probes.probabilities(hidden)
    for h, names in NAMES.items():
        assert a.atoms[h] == tuple(names) and a.values[h].dtype == bool
        for j, name in enumerate(names):
            if j in KEPT[h]:
                assert a.probed[h][j] and a.probs[h][j] == pytest.approx(expected[name], abs=1e-5)
                assert a.values[h][j] == (expected[name] > 0.5)
            else:
                assert not a.probed[h][j] and np.isnan(a.probs[h][j])
                assert a.values[h][j] == (FREQ[h][j] >= 0.5)
    assert readout.layers == {"object": 1, "action": 2}


def test_a_stored_episode_read_row_by_row_gives_identical_predictions() -> None:
    readout = ProbeReadout(probe_set(), layers={"object": 0, "action": 0})
    hidden = np.random.default_rng(2).standard_normal((LAYERS, 5, HIDDEN)).astype(np.float16)  # (L, T, H)
    batch = readout.assign_steps({h: hidden[0] for h in NAMES})
    for t in range(5):
        one = readout.assign(hidden[:, t])
        for h in NAMES:
            assert np.array_equal(batch.values[h][t], one.values[h])
            assert np.array_equal(batch.probs[h][t], one.probs[h], equal_nan=True)


def test_action_token_pooling_averages_the_seven_positions() -> None:
    probes = probe_set(pooling="action_tokens")
    hidden = np.random.default_rng(3).standard_normal((LAYERS, 7, HIDDEN)).astype(np.float32)
    a = ProbeReadout(probes).assign(hidden)
    expected = probes.probabilities(hidden)  # ProbeSet averages the 7 positions itself
    assert a.probs["object"][0] == pytest.approx(expected[NAMES["object"][0]], abs=1e-5)


def test_bad_hidden_states_and_layers_are_one_line_errors(tmp_path: Path) -> None:
    readout = ProbeReadout(probe_set())
    with pytest.raises(VlaprobeError, match="do not fit these probes"):
        readout.assign(np.zeros((LAYERS, HIDDEN + 1)))
    with pytest.raises(VlaprobeError, match="no object probe for hidden state 7"):
        ProbeReadout(probe_set(), layers={"object": 7})
    with pytest.raises(VlaprobeError, match="not a probe folder"):
        ProbeReadout.load(tmp_path)


def test_a_head_without_probes_reads_as_unknown_only_when_allowed() -> None:
    """`vlaprobe cognition` on an object-only folder: the action atoms are all unknown (not probed, false); the
    readout of the live server (no ``unknown``) still refuses the folder."""
    probes = probe_set(without="action")
    with pytest.raises(VlaprobeError, match="have no 'action' head; the cognition needs it"):
        ProbeReadout(probes)
    readout = ProbeReadout(probes, unknown={"action": NAMES["action"]})
    assert readout.unknown == ("action",) and readout.layers == {"object": 1}
    hidden = np.random.default_rng(4).standard_normal((LAYERS, 5, HIDDEN)).astype(np.float32)
    batch = readout.assign_steps({"object": hidden[1]})
    assert batch.values["action"].shape == (5, 3) and not batch.values["action"].any()
    assert np.isnan(batch.probs["action"]).all() and not batch.probed["action"].any()
    one = readout.assign(hidden[:, 0])
    assert np.array_equal(one.values["object"], batch.values["object"][0]) and not one.values["action"].any()
    expected = probes.probabilities(hidden[1, 0], head="object", layer=1)
    assert one.probs["object"][0] == pytest.approx(expected[NAMES["object"][0]], abs=1e-5)
