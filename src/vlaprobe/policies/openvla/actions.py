"""From action token ids to the 7-D command LIBERO executes, exactly as OpenVLA's LIBERO evaluation does.

Two layers, kept apart because OpenVLA keeps them apart:

- :func:`decode_action` is ``OpenVLAForActionPrediction.predict_action`` after ``generate``: token id t →
  bin ``clip(32000 − t − 1, 0, 254)`` → the bin's centre in [−1, 1] (the 255 midpoints of
  ``linspace(−1, 1, 256)``) → un-normalised with the dataset's q01/q99 where ``mask`` is true (the gripper
  keeps its [0, 1]-ish normalised value). float64 throughout.
- :func:`libero_gripper` is ``run_libero_eval.py``'s ``normalize_gripper_action(binarize=True)`` then
  ``invert_gripper_action``: gripper g → sign(2g − 1) → negated, so −1 opens and +1 closes.
"""

from __future__ import annotations

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject


def bin_centers(n_action_bins: int = 256) -> np.ndarray:
    """The n_action_bins − 1 midpoints of ``linspace(−1, 1, n_action_bins)``."""
    bins = np.linspace(-1, 1, n_action_bins)
    return (bins[:-1] + bins[1:]) / 2.0


def resolve_unnorm_key(norm_stats: JsonObject, unnorm_key: str | None, suite: str = "libero_spatial") -> str:
    """``unnorm_key`` if present, else ``unnorm_key + "_no_noops"`` (OpenVLA's LIBERO fallback). ``None`` means the
    suite's statistics (``libero_goal`` → ``libero_goal``, else ``libero_goal_no_noops``, the key of OpenVLA's
    LIBERO fine-tunes); a checkpoint without them but with one key only uses that one, as OpenVLA does with no
    key (a single-dataset model un-normalises one way)."""
    key = suite if unnorm_key is None else unnorm_key
    if key in norm_stats:
        return key
    if f"{key}_no_noops" in norm_stats:
        return f"{key}_no_noops"
    if unnorm_key is None and len(norm_stats) == 1:
        return next(iter(norm_stats))
    raise VlaprobeError(
        f"action statistics {key!r} not in the checkpoint (has {sorted(norm_stats)}); "
        "pass one of those as --policy.unnorm-key or add dataset_statistics.json"
    )


def action_stats(norm_stats: JsonObject, key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q01, q99, mask) of ``norm_stats[key]["action"]`` (``key`` as :func:`resolve_unnorm_key` resolves it); a
    missing mask means all dimensions."""
    key = resolve_unnorm_key(norm_stats, key)
    try:
        stats = norm_stats[key]["action"]
        q01 = np.asarray(stats["q01"], dtype=np.float64)
        q99 = np.asarray(stats["q99"], dtype=np.float64)
        mask = np.asarray(stats.get("mask", np.ones_like(q01, dtype=bool)), dtype=bool)
    except (KeyError, TypeError, ValueError) as exc:
        raise VlaprobeError(
            f"malformed action statistics for {key!r} ({exc}); fix dataset_statistics.json"
        ) from None
    if not (q01.shape == q99.shape == mask.shape) or q01.ndim != 1:
        raise VlaprobeError(
            f"action statistics for {key!r} have mismatched shapes; fix dataset_statistics.json"
        )
    return q01, q99, mask


def decode_action(
    token_ids: np.ndarray,
    q01: np.ndarray,
    q99: np.ndarray,
    mask: np.ndarray,
    vocab_end: int = 32000,
    n_action_bins: int = 256,
) -> np.ndarray:
    """Token ids (7,) → ``predict_action``'s un-normalised action (7,) float64 (gripper still in [0, 1])."""
    centers = bin_centers(n_action_bins)
    index = np.clip(vocab_end - np.asarray(token_ids, dtype=np.int64) - 1, 0, centers.shape[0] - 1)
    normalized = centers[index]
    return np.where(mask, 0.5 * (normalized + 1) * (q99 - q01) + q01, normalized)


def normalize_action(action: np.ndarray, q01: np.ndarray, q99: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """OpenVLA's ``BOUNDS_Q99`` normalisation of (..., 7) actions: ``clip(2(a − q01)/(q99 − q01 + 1e-8) − 1,
    −1, 1)`` where ``mask`` is true; the other dimensions (the gripper) pass through unchanged. float64."""
    a = np.asarray(action, dtype=np.float64)
    scaled = np.clip(2 * (a - q01) / (q99 - q01 + 1e-8) - 1, -1, 1)
    return np.where(mask, scaled, a)


def encode_action(normalized: np.ndarray, vocab_end: int = 32000, n_action_bins: int = 256) -> np.ndarray:
    """prismatic's ``ActionTokenizer``: normalised (..., 7) actions → token ids ``vocab_end − digitize(clip(a,
    −1, 1), linspace(−1, 1, n_action_bins))`` (int64), the inverse of :func:`decode_action`'s binning."""
    bins = np.linspace(-1, 1, n_action_bins)
    return vocab_end - np.digitize(np.clip(normalized, -1, 1), bins).astype(np.int64)


def training_gripper(libero_action: np.ndarray) -> np.ndarray:
    """LIBERO's executed action (gripper −1 open, +1 close) → OpenVLA's training target on a copy, as its
    ``libero_dataset_transform`` does: gripper g → 1 − clip(g, 0, 1) (1 open, 0 closed). Inverse of
    :func:`libero_gripper` on ±1."""
    out = np.array(libero_action, dtype=np.float64, copy=True)
    out[..., -1] = 1 - np.clip(out[..., -1], 0, 1)
    return out


def libero_gripper(action: np.ndarray) -> np.ndarray:
    """OpenVLA's LIBERO gripper post-processing on a copy: g → −sign(2g − 1) (−1 open, +1 close)."""
    out = np.array(action, dtype=np.float64, copy=True)
    out[..., -1] = -np.sign(2 * out[..., -1] - 1)
    return out
