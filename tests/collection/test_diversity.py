"""Diversity figures on hand-made episodes with a known answer."""

from __future__ import annotations

import numpy as np

from vlaprobe.collection.diversity import diversity, head_diversity, summary_lines

T, F = True, False


def test_counts_on_hand_made_episodes() -> None:
    a = np.array([[T, F, F], [T, T, F], [T, T, F]])  # atom 1 changes
    b = np.array([[T, F, F], [F, F, F]])  # atom 0 changes; its first row equals a's
    c = np.array([[T, F, T]])  # one row: nothing can change
    h = head_diversity(["x", "y", "z"], [a, b, c])
    assert h.episodes_varying == (1, 1, 0)
    assert h.varying == 2
    np.testing.assert_allclose(h.base_rate, [5 / 6, 2 / 6, 1 / 6])
    # distinct rows: TFF, TTF, FFF, TFT
    assert h.distinct_states == 4 and h.distinct_first_states == 2
    assert h.ever_true == 3 and h.always_true == 0


def test_both_heads_and_the_summary() -> None:
    names = {"object": ["x", "y"], "action": ["g"]}
    eps = [
        {"object": np.array([[T, F], [T, F]]), "action": np.array([[F], [T]])},
        {"object": np.array([[T, T]]), "action": np.array([[F]])},
    ]
    d = diversity(names, eps, perturbed_episodes=1)
    assert d.episodes == 2 and d.rows == 3 and d.perturbed_episodes == 1
    assert d.heads["object"].varying == 0 and d.heads["action"].varying == 1
    assert d.heads["object"].always_true == 1  # x
    out = d.as_dict()
    assert out["heads"]["action"]["episodes_varying"] == {"g": 1}
    assert out["heads"]["object"]["distinct_states"] == 2
    text = "\n".join(summary_lines(d))
    assert "0 of 2 atoms change" in text and "1 of 1 atoms change" in text
