"""The paper's open hypotheses, answered with intervals.

H1: object states are encoded in earlier layers than action states. H2: action states peak in later layers.
Per head, from its metric-versus-layer curve (balanced accuracy on the test episodes, the mean over the
head's kept atoms: the ``layer`` level of ``evaluation.json``, computed by the same functions of
``vlaprobe.probes.metrics`` on the same bootstrap resamples, so curve and per-layer intervals equal it):

- **best**: the layer of the highest value (first on ties);
- **earliest**: the first layer whose value is within the best layer's interval (at least the best value minus
  the half-width of the best layer's 95 % interval): where the head is already as good as it gets;
- **steepest**: the layer of the curve's steepest rise (largest increase over the previous layer). The rise
  from hidden state 0 is left out when state 0 is on the curve: with last-token pooling it is a fixed token
  embedding, so its poor score and the jump after it are automatic.

The object-minus-action difference of each statistic gets a percentile interval from bootstrap resamples of
the test episodes (``vlaprobe.probes.bootstrap``), drawn **jointly** for both heads (the same resampled
episodes score both), so the interval accounts for their correlation. H1 is read on ``earliest`` (negative
supports it), H2 on ``best`` (negative: the action head peaks later, supports it); an interval that holds 0
cannot tell.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from vlaprobe.probes.bootstrap import interval
from vlaprobe.probes.metrics import count_metrics, layer_means

STATISTICS = ("best", "earliest", "steepest")
MIN_EPISODES = 8
"""Fewer test episodes than this give too few distinct resamples for an interval to decide: "cannot tell"."""


@dataclass(frozen=True)
class LayerCurves:
    """A metric per layer for two heads on the test episodes, and on bootstrap resamples of those episodes."""

    layers: tuple[int, ...]
    """Hidden-state index of each curve point."""
    point: Mapping[str, np.ndarray]
    """Head ("object", "action") -> (layers,) metric on all test episodes."""
    resamples: Mapping[str, np.ndarray]
    """Head -> (resamples, layers): row b of every head is computed on the same resampled episodes. NaN where a
    resample leaves the metric undefined at every atom."""
    metric: str = "balanced_accuracy"
    episodes: int | None = None
    """Test episodes the resamples were drawn from (None: unknown, e.g. synthetic curves)."""


@dataclass(frozen=True)
class HeadLayers:
    """The three layer statistics of one head, each with its bootstrap interval (2.5 and 97.5 percentiles)."""

    best: int
    best_interval: tuple[int, int]
    best_value: float
    best_value_interval: tuple[float, float]
    earliest: int
    earliest_interval: tuple[int, int]
    steepest: int
    steepest_interval: tuple[int, int]


@dataclass(frozen=True)
class Difference:
    """Object minus action of one statistic (in layers), with its joint-bootstrap interval."""

    statistic: str
    value: float
    low: float
    high: float


@dataclass(frozen=True)
class Verdict:
    """What the data say about one hypothesis."""

    hypothesis: str
    """"H1" or "H2"."""
    claim: str
    statistic: str
    verdict: str
    """"support", "contradict" or "cannot tell"."""
    sentence: str


@dataclass(frozen=True)
class Hypotheses:
    """Per head layer statistics, the object-minus-action differences, and one verdict per hypothesis."""

    metric: str
    resamples: int
    episodes: int | None
    heads: dict[str, HeadLayers]
    differences: dict[str, Difference]
    verdicts: list[Verdict]

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def layer_statistics(curve: np.ndarray, layers: Sequence[int], tolerance: float) -> dict[str, int]:
    """best, earliest (within ``tolerance`` of the best value) and steepest layer of one curve."""
    c = np.where(np.isfinite(curve), curve, -np.inf)
    best = int(np.argmax(c))
    earliest = int(np.flatnonzero(c >= c[best] - tolerance)[0])
    start = 1 if layers[0] == 0 and len(layers) > 2 else 0  # skip the rise out of the token embedding
    rises = np.diff(c[start:])
    rises = np.where(np.isfinite(rises), rises, -np.inf)
    steepest = start + 1 + int(np.argmax(rises)) if len(rises) else best
    return {"best": layers[best], "earliest": layers[earliest], "steepest": layers[steepest]}


def _head(curves: LayerCurves, head: str) -> tuple[HeadLayers, dict[str, np.ndarray]]:
    layers, point, boot = curves.layers, curves.point[head], curves.resamples[head]
    best_i = int(np.argmax(np.where(np.isfinite(point), point, -np.inf)))
    low, high = interval(boot[:, best_i])
    tolerance = 0.5 * (high - low) if np.isfinite(low) else 0.0
    stats = layer_statistics(point, layers, tolerance)
    per = {
        s: np.array([layer_statistics(row, layers, tolerance)[s] for row in boot], float) for s in STATISTICS
    }

    def iv(s: str) -> tuple[int, int]:
        a, b = interval(per[s])
        return (round(a), round(b))

    result = HeadLayers(
        best=stats["best"],
        best_interval=iv("best"),
        best_value=float(point[best_i]),
        best_value_interval=(low, high),
        earliest=stats["earliest"],
        earliest_interval=iv("earliest"),
        steepest=stats["steepest"],
        steepest_interval=iv("steepest"),
    )
    return result, per


def _verdict(
    hypothesis: str, claim: str, d: Difference, heads: dict[str, HeadLayers], what: str, episodes: int | None
) -> Verdict:
    few = episodes is not None and episodes < MIN_EPISODES
    if few or np.isnan(d.high):  # NaN: no resample defined it
        verdict = "cannot tell"
    elif d.high < 0:
        verdict = "support"
    elif d.low > 0:
        verdict = "contradict"
    else:
        verdict = "cannot tell"
    o, a = getattr(heads["object"], d.statistic), getattr(heads["action"], d.statistic)
    says = {"support": "support it", "contradict": "contradict it", "cannot tell": "cannot tell"}[verdict]
    sentence = (
        f"{hypothesis} ({claim}): the data {says}. {what} is layer {o} for object states and {a} for action "
        f"states; object minus action {d.value:+.0f} layers (95% interval {d.low:+.1f} to {d.high:+.1f})."
    )
    if few:
        sentence += (
            f" Only {episodes} test episodes (fewer than {MIN_EPISODES}): too few for the interval to decide."
        )
    return Verdict(hypothesis, claim, d.statistic, verdict, sentence)


def answer_hypotheses(curves: LayerCurves) -> Hypotheses:
    """Layer statistics per head, object-minus-action differences with joint-bootstrap intervals, verdicts."""
    if set(curves.point) < {"object", "action"}:
        raise ValueError(f"H1/H2 need an object and an action curve, got {sorted(curves.point)}")
    b = {len(curves.resamples["object"]), len(curves.resamples["action"])}
    if len(b) != 1:
        raise ValueError("both heads need the same (jointly drawn) resamples")
    obj, obj_per = _head(curves, "object")
    act, act_per = _head(curves, "action")
    heads = {"object": obj, "action": act}
    differences = {}
    for s in STATISTICS:
        low, high = interval(obj_per[s] - act_per[s])
        differences[s] = Difference(s, float(getattr(obj, s) - getattr(act, s)), low, high)
    verdicts = [
        _verdict(
            "H1",
            "object states are encoded in earlier layers than action states",
            differences["earliest"],
            heads,
            "The earliest layer within the best layer's interval",
            curves.episodes,
        ),
        _verdict(
            "H2",
            "action states peak in later layers",
            differences["best"],
            heads,
            "The best layer",
            curves.episodes,
        ),
    ]
    return Hypotheses(curves.metric, b.pop(), curves.episodes, heads, differences, verdicts)


# ----- curves from confusion counts ---------------------------------------------------------------------------
def curves_from_counts(
    counts: Mapping[str, np.ndarray], layers: Sequence[int], weights: np.ndarray
) -> LayerCurves:
    """:class:`LayerCurves` of balanced accuracy per head from its per-episode confusion counts (episodes,
    layers, atoms, 4) (:func:`~vlaprobe.probes.metrics.confusion_by_group`) and one set of resample
    multiplicities (resamples, episodes) (:func:`~vlaprobe.probes.bootstrap.bootstrap_weights`), used for
    every head. The curve is :func:`~vlaprobe.probes.metrics.layer_means` of the per-atom balanced accuracy,
    as ``evaluation.json``'s ``layer`` level."""
    point, boot = {}, {}
    for head, c in counts.items():
        p, r = count_metrics(c, weights)
        point[head], boot[head] = layer_means(p["balanced_accuracy"], r["balanced_accuracy"])
    return LayerCurves(tuple(int(x) for x in layers), point, boot, episodes=int(weights.shape[1]))
