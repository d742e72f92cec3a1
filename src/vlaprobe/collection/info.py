"""``vlaprobe info DIR [--json]``: what an activation store holds."""

from __future__ import annotations

import json
import os
from collections import defaultdict
from pathlib import Path

from vlaprobe.collection.diversity import store_diversity, summary_lines
from vlaprobe.collection.store import ActivationStore
from vlaprobe.collection.verify import Damage, check_store, describe, repair_hint
from vlaprobe.configs.collect import InfoConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject


def _bytes(path: Path) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files)


def summarize(path: str | Path) -> JsonObject:
    """The store's summary (``--json`` output): episodes, layers, hidden size, pooling, model, size..."""
    store = ActivationStore.open(path)
    return {
        **store.summary(),
        "bytes": _bytes(Path(path)),
        "instructions": store.metadata.instructions,
        "undefined": {h: {"atoms": a, "episodes": e} for h, (a, e) in store.undefined().items()},
    }


def info(cfg: InfoConfig) -> int:
    s = summarize(cfg.path)
    damage = check_store(cfg.path, read=cfg.verify)
    s["damaged"] = [{"key": d.key, "problem": d.problem} for d in damage]
    div = store_diversity(cfg.path) if not damage else None
    s["diversity"] = div.as_dict() if div is not None else None
    if cfg.json:
        print(json.dumps(s))
        return _fail(cfg.path, damage)
    per_task: dict[int, list[JsonObject]] = defaultdict(list)
    for e in s["episodes"]:
        per_task[e["task"]].append(e)
    ok = sum(e["success"] for e in s["episodes"])
    print(f"store     {s['path']} (format {s['format_version']}, {s['bytes'] / 2**20:.1f} MiB)")
    print(
        f"model     {s['model_id']}: {s['layers']} hidden states x {s['hidden_size']}, pooling {s['pooling']}"
    )
    print(f"driver    {s['driver']}; atoms: " + ", ".join(f"{n} {head}" for head, n in s["atoms"].items()))
    if any(u["episodes"] for u in s["undefined"].values()):  # a union store: tasks with different objects
        parts = [f"{head} {u['atoms']} atoms in {u['episodes']}" for head, u in s["undefined"].items()]
        print(f"undefined {'; '.join(parts)} of {len(s['episodes'])} episodes (never scored)")
    print(
        f"episodes  {len(s['episodes'])} ({ok} successful), {s['steps']} steps; "
        f"{len(s['failures'])} failed tries recorded without data"
    )
    if per_task:
        print(f"{'task':>4}  {'episodes':>8}  {'successful':>10}  {'steps':>6}  instruction")
        for task, eps in sorted(per_task.items()):
            text = s["instructions"].get(str(task), "")
            print(
                f"{task:>4}  {len(eps):>8}  {sum(e['success'] for e in eps):>10}  "
                f"{sum(e['length'] for e in eps):>6}  {text}"
            )
    if div is not None:
        print("\n".join(summary_lines(div)))
    return _fail(cfg.path, damage)


def _fail(path: Path, damage: list[Damage]) -> int:
    """After the summary: a damaged store is an error naming the episodes and the repair."""
    if damage:
        raise VlaprobeError(f"{describe(path, damage)}; {repair_hint(path, damage)}")
    return 0
