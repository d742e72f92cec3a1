"""Has a fine-tuned model fit its demonstrations? Teacher-forced figures on its training rows and validation rows.

    .venv/bin/python scripts/fit_check.py tiny-libero runs/tiny-libero/demos-i0 runs/tiny-libero/demos-i10

Splits the stores as ``vlaprobe finetune`` does with the given ``--val-fraction``/``--seed`` (the recipes'
defaults: 0.1 and 0), bins the actions with the model's own ``norm_stats``, and scores ``--rows`` rows spread
evenly over each side. A model whose training accuracy is barely above its validation accuracy is underfit
(more steps help); one far above it does not generalise (more data helps). docs/tiny-libero.md quotes it.
Prints one line per side and a final JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.finetune.data import load_demonstrations, split_episodes
from vlaprobe.finetune.evaluate import validate
from vlaprobe.finetune.examples import ActionStats, make_examples
from vlaprobe.policies.factory import make_policy
from vlaprobe.policies.openvla.policy import OpenVLAPolicy


def evenly(rows: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` of ``rows``, evenly spread (as ``--val-max-samples`` thins the validation rows)."""
    if len(rows) <= n:
        return rows
    return rows[np.unique(np.linspace(0, len(rows) - 1, n).round().astype(np.int64))]


def fit_check(
    model: str, stores: tuple[Path, ...], val_fraction: float, seed: int, n: int
) -> dict[str, dict]:
    """Token accuracy, L1 and loss of ``model`` on ``n`` training and ``n`` validation rows."""
    policy = make_policy(PolicyConfig(model, device="cpu"))
    if not isinstance(policy, OpenVLAPolicy):
        raise VlaprobeError(f"{model} is not an OpenVLA model; pass a checkpoint folder or a shipped name")
    net = policy.model.float().eval()
    a = policy.norm_stats[policy.unnorm_key]["action"]
    stats = ActionStats(np.asarray(a["q01"]), np.asarray(a["q99"]), np.asarray(a["mask"], dtype=bool))
    demos = load_demonstrations(stores, net.config.featurizer.image_size)
    split = split_episodes(demos, val_fraction, seed)
    examples = make_examples(demos, policy.tokenizer, stats, net)
    out = {}
    for side, rows in (("train", split.train), ("val", split.val)):
        v = validate(net, examples, evenly(rows, n), stats, torch.device("cpu"), 32)
        out[side] = {"accuracy": v.accuracy, "l1": v.l1, "loss": v.loss, "rows": v.samples}
        print(f"{side}: token accuracy {v.accuracy:.3f}, L1 {v.l1:.4f}, loss {v.loss:.3f} ({v.samples} rows)")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", help="a checkpoint folder or a shipped model's name")
    parser.add_argument("stores", nargs="+", type=Path, help="the collection stores it was trained on")
    parser.add_argument("--val-fraction", type=float, default=0.1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rows", type=int, default=500, help="rows scored per side")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    try:
        result = fit_check(args.model, tuple(args.stores), args.val_fraction, args.seed, args.rows)
    except VlaprobeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
