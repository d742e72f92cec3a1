"""Files of a probe folder made for tests through the real dataclasses (to be written by the real writers)."""

from __future__ import annotations

from pathlib import Path

from vlaprobe.probes.results import (
    BestLayer,
    Bootstrap,
    Controls,
    Dataset,
    Episodes,
    Evaluation,
    HeadResult,
    Level,
    MetricSummary,
    Split,
)


def evaluation_with_split(
    test_episodes: list[str],
    model_id: str = "fake",
    layers: list[int] | None = None,
    hidden_size: int = 8,
    heads: dict[str, HeadResult] | None = None,
    folds: int = 1,
) -> Evaluation:
    """An :class:`Evaluation` whose split holds out ``test_episodes`` (and ``heads`` if given, else none)."""
    n = len(test_episodes)
    return Evaluation(
        model_id=model_id,
        pooling="last_prompt",
        layers=list(layers or [0]),
        hidden_size=hidden_size,
        threshold=0.5,
        metrics=["balanced_accuracy"],
        dataset=Dataset(episodes=2 * n, steps=20 * n, episodes_per_task={"0": 2 * n}),
        split=Split(
            unit="episode",
            stratified_by="task",
            folds=folds,
            test_fraction=0.5,
            realized_test_fraction=0.5,
            train=Episodes(episodes=n, steps=10 * n),
            test=Episodes(episodes=n, steps=10 * n),
            test_episodes=list(test_episodes),
            leak_check="passed",
        ),
        bootstrap=Bootstrap("test episode", "95% percentile", 10, 0, "as in vlaprobe train"),
        controls=Controls(shuffled_labels=False, shuffled_permutations=0),
        heads=dict(heads or {}),
        config={},
        seeds={},
        versions={},
    )


def head_result(predicates: list[str], values: list[list[float]], best: int, layers: list[int]) -> HeadResult:
    """A head whose per-predicate balanced accuracy is ``values`` (layers, predicates), interval [v - 0.05, v],
    with one atom per predicate and ``best`` the index of its best layer."""
    low = [[v - 0.05 for v in row] for row in values]
    per_layer = [sum(row) / len(row) for row in values]
    level = Level(value=values, low=low, high=values, defined=[[10] * len(row) for row in values])
    summary = MetricSummary(
        atom=level,
        predicate=level,
        layer=Level(value=per_layer, low=per_layer, high=per_layer, defined=[10] * len(values)),
    )
    atoms = [f"{p}(a)" for p in predicates]
    v = per_layer[best]
    return HeadResult(
        atoms=atoms,
        predicates=list(predicates),
        predicate_atoms={p: [a] for p, a in zip(predicates, atoms, strict=True)},
        skipped_predicates=[],
        dropped=[],
        train_frequency=[0.5] * len(atoms),
        test_frequency=[0.5] * len(atoms),
        best=BestLayer(layers[best], best, "balanced_accuracy", v, v, v, "highest value"),
        probe={"balanced_accuracy": summary},
        baseline={"balanced_accuracy": summary},
    )


def probes_for_report(folder: Path) -> Path:
    """A small probe folder trained on synthetic data (seconds), for tests that render the report page."""
    from vlaprobe.configs.train import ProbeConfig, TrainConfig
    from vlaprobe.probes import synthetic_data, train_on_data

    data = synthetic_data(
        num_tasks=2, episodes_per_task=3, steps_per_episode=10, num_layers=2, hidden_size=8, num_object=6,
        num_action=2, seed=0,
    )  # fmt: skip
    fast = TrainConfig(
        bootstrap=5, auprc_bootstrap=0, shuffled_permutations=1, probe=ProbeConfig(c_grid=(0.1,), max_iter=50)
    )
    return train_on_data(data, fast, folder)
