"""Show a store's recorded episodes to another model: same images, atoms, actions and world states; that model's
hidden states.

Why: comparing two observers (``vlaprobe run``: the trained tiny model and the random control) is only fair on
exactly the same episodes. The images a store keeps are the ones the first observer was given, after the
LIBERO preprocessing, which does not depend on the model; so the second observer's states come from a batched
prompt pass over them (:meth:`OpenVLAPolicy.observe`) instead of a second simulation. The copy omits the first
observer's ``predicted_action`` and ``action_tokens``. Resumable like collection: episodes already copied are
kept, and a rerun adds the rest.
"""

from __future__ import annotations

import shlex
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from vlaprobe.collection.store import ActivationStore, EpisodeInfo
from vlaprobe.collection.writer import StoreWriter
from vlaprobe.configs.policy import PolicyConfig
from vlaprobe.configs.stores import ReobserveConfig
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject
from vlaprobe.policies.base import VLAPolicy


@runtime_checkable
class Observer(Protocol):
    """A model that computes hidden states of stored images in batches (``OpenVLAPolicy.observe``)."""

    def observe(self, model_images: np.ndarray, instruction: str) -> np.ndarray: ...


SOURCE_ONLY = frozenset({"hidden", "predicted_action", "action_tokens"})
"""Arrays of the source episode that belong to its observer and are not copied."""
EPISODE_KEYS = frozenset(EpisodeInfo.__dataclass_fields__)


def _meta(source: ActivationStore, policy: VLAPolicy, cfg: PolicyConfig) -> JsonObject:
    from vlaprobe.collection.collect import VOLATILE_MODEL_KEYS

    kept = {
        k: v for k, v in source.meta.items() if k not in ("runs", "created", "command", "all_chunks_written")
    }
    return {
        **kept,
        "model_id": policy.model_id,
        "model": {k: v for k, v in policy.describe().items() if k not in VOLATILE_MODEL_KEYS},
        "num_hidden_states": int(policy.num_hidden_states),
        "hidden_size": int(policy.hidden_size),
        "pooling": str(policy.pooling),
        "reobserved_from": {"path": str(source.path), "model_id": source.model_id},
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "runs": [],
    }


def episode_hidden(policy: Observer, images: np.ndarray, instruction: str, batch: int) -> np.ndarray:
    """(layers, T, hidden) float16 states of ``policy`` for an episode's (T, 224, 224, 3) model images."""
    parts = [policy.observe(images[i : i + batch], instruction) for i in range(0, len(images), batch)]
    return np.ascontiguousarray(np.moveaxis(np.concatenate(parts), 0, 1)).astype(np.float16)


def reobserve(source: str | Path, out: str | Path, cfg: PolicyConfig, batch: int = 16) -> list[str]:
    """Copy every episode of the store ``source`` into the store ``out`` with ``cfg``'s model as the observer;
    return the keys added. The model runs with ``cfg.pooling``; the store's images must exist."""
    from vlaprobe.policies.factory import make_policy

    store = ActivationStore.open(source)
    if Path(out).resolve() == store.path.resolve():
        raise VlaprobeError(f"reobserve writes a new store; choose an --out other than the source {source}")
    policy = make_policy(cfg, store.suite)
    if not isinstance(policy, Observer):
        raise VlaprobeError(f"model {cfg.model!r} cannot re-observe stored images; use an OpenVLA model")
    added: list[str] = []
    start = time.perf_counter()
    with StoreWriter.open(out, _meta(store, policy, cfg)) as writer:
        done = set(writer.outcomes())
        for info, ep in store.iter_episodes():
            if info.key in done:
                continue
            if "image" not in ep:
                raise VlaprobeError(f"episode {info.key} of {source} has no images; re-collect it")
            arrays = {name: ep[name] for name in ep if name not in SOURCE_ONLY}
            arrays["hidden"] = episode_hidden(policy, ep["image"], ep.attributes.instruction, batch)
            attrs = {k: v for k, v in ep.attrs.items() if k not in EPISODE_KEYS}
            writer.write_episode(info, arrays, attrs)
            added.append(info.key)
        for info in store.failures():
            if info.key not in done:
                writer.mark_failed(info)
        run = {"command": shlex.join(sys.argv), "seconds": round(time.perf_counter() - start, 1)}
        writer.update_meta(runs=[*writer.meta.get("runs", []), {**run, "episodes_added": len(added)}])
    return added


def main(cfg: ReobserveConfig) -> int:
    """``vlaprobe reobserve``: copy the store with ``--model`` as the observer; print what was added."""
    if cfg.batch < 1:
        raise VlaprobeError(f"--batch must be at least 1, got {cfg.batch}")
    out = cfg.out or Path(cfg.store).with_name(f"{Path(cfg.store).name}-{Path(cfg.policy.model).name}")
    added = reobserve(cfg.store, out, cfg.policy, cfg.batch)
    total = len(ActivationStore.open(out).episodes())
    print(f"{out}: {len(added)} episodes observed by {cfg.policy.model} ({total} in the store)")
    return 0
