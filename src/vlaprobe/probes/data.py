"""The probes' input: hidden states of every layer with the labels of the same steps.

:class:`ProbeData` is built from an activation store (:func:`load_store`) or synthetically with planted
linear structure (:func:`synthetic_data`, for tests and the benchmark).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.vocabulary import ACTION_PREDICATES, HEADS, OBJECT_PREDICATES
from vlaprobe.symbols.vocabulary import predicate_of as predicate

# The paper's figure order of predicates, and an atom's predicate, are the vocabulary's.
__all__ = ["ACTION_PREDICATES", "OBJECT_PREDICATES", "ProbeData", "load_store", "predicate", "synthetic_data"]


@dataclass
class ProbeData:
    """Pooled hidden states of a set of episodes and the symbolic labels of the same steps (rows)."""

    hidden: torch.Tensor
    """(layers, steps, hidden_size), float16 or float32: one vector per step and probed hidden state."""
    layers: list[int]
    """Hidden-state index (0 = embeddings) of each entry of ``hidden``'s first axis."""
    labels: dict[str, np.ndarray]
    """Head ("object", "action") -> bool (steps, atoms)."""
    atom_names: dict[str, list[str]]
    """Head -> canonical atom names, the columns of ``labels[head]``."""
    episode: np.ndarray
    """int (steps,): position of each step's episode in ``episode_keys``."""
    episode_keys: list[str]
    """Unique key of each episode."""
    episode_tasks: np.ndarray
    """int (episodes,): task index of each episode."""
    model_id: str
    """Observer model whose hidden states these are."""
    pooling: str
    """How the store pooled token positions into one vector per step."""
    num_hidden_states: int
    """Hidden states the model has (33 for OpenVLA), even if only some are loaded."""
    suite: str = "libero_spatial"
    """The LIBERO suite of the episodes."""
    defined: dict[str, np.ndarray] = field(default_factory=dict)
    """Head -> bool (steps, atoms): False where the atom is undefined in that step's episode (union stores);
    a head not listed is all defined. Read it through :meth:`defined_mask`."""

    def __post_init__(self) -> None:
        n = self.hidden.shape[1]
        if self.hidden.ndim != 3 or len(self.layers) != self.hidden.shape[0]:
            raise ValueError(
                f"hidden must be (layers={len(self.layers)}, steps, hidden); got {tuple(self.hidden.shape)}"
            )
        if self.episode.shape != (n,):
            raise ValueError(f"episode must have one entry per step ({n}); got {self.episode.shape}")
        for head, y in self.labels.items():
            if y.shape != (n, len(self.atom_names[head])):
                raise ValueError(
                    f"labels[{head!r}] must be ({n}, {len(self.atom_names[head])}); got {y.shape}"
                )
        for head, m in self.defined.items():
            if m.shape != self.labels[head].shape:
                raise ValueError(f"defined[{head!r}] must have labels' shape {self.labels[head].shape}")
        if len(self.episode_tasks) != len(self.episode_keys):
            raise ValueError("episode_tasks and episode_keys must have the same length")

    @property
    def num_steps(self) -> int:
        return int(self.hidden.shape[1])

    @property
    def hidden_size(self) -> int:
        return int(self.hidden.shape[2])

    def defined_mask(self, head: str) -> np.ndarray:
        """bool (steps, atoms): which entries of ``labels[head]`` are defined (all, for single-vocabulary stores)."""
        return self.defined.get(head, np.ones_like(self.labels[head], dtype=bool))

    def partly_defined(self, head: str) -> np.ndarray | None:
        """:meth:`defined_mask`, or None where every entry is defined (the figures are then computed exactly as
        without a mask)."""
        mask = self.defined_mask(head)
        return None if mask.all() else mask

    def targets_defined(self, kept: dict[str, np.ndarray]) -> np.ndarray | None:
        """bool (steps, columns) aligned with the targets ``labels[h][:, kept[h]]`` of each head in turn (None:
        all defined)."""
        if all(self.partly_defined(h) is None for h in kept):
            return None
        return np.concatenate([self.defined_mask(h)[:, cols] for h, cols in kept.items()], axis=1)

    @property
    def heads(self) -> list[str]:
        return list(self.labels)


def load_store(
    path: str | Path,
    heads: Sequence[str] = HEADS,
    layers: Sequence[int] = (),
    success_only: bool = False,
) -> ProbeData:
    """Read the hidden states and labels of every complete episode of an activation store.

    Pooling "action_tokens" stores (steps, 7, hidden) per layer; the 7 action-token positions are averaged
    into one vector, so every pooling gives the probes one ``hidden_size`` vector per step.
    """
    from vlaprobe.collection.store import ActivationStore
    from vlaprobe.collection.verify import require_intact

    store = ActivationStore.open(path)
    require_intact(path)  # a missing chunk would read as zeros; truncated ones fail when read (one line too)
    missing = [h for h in heads if h not in store.atom_names]
    if missing:
        raise VlaprobeError(
            f"store {path} has no label head(s) {missing}; use --heads with some of {list(store.atom_names)}"
        )
    episodes = store.episodes(success_only=success_only)
    if len(episodes) < 2:
        what = "successful " if success_only else ""
        raise VlaprobeError(
            f"store {path} has {len(episodes)} complete {what}episode(s); probing needs at least 2, collect more"
        )
    layer_ids = list(layers) if layers else list(range(store.num_hidden_states))
    bad = [i for i in layer_ids if not 0 <= i < store.num_hidden_states]
    if bad:
        raise VlaprobeError(
            f"layers {bad} do not exist; the store has hidden states 0..{store.num_hidden_states - 1}"
        )
    keys = [e.key for e in episodes]
    steps = sum(e.length for e in episodes)
    hidden = np.empty((len(layer_ids), steps, store.hidden_size), np.float16)
    for i, layer in enumerate(layer_ids):
        h = store.layer(layer, keys)
        if h.ndim == 3:  # action_tokens: average the action-token positions
            h = h.astype(np.float32).mean(axis=1)
        if h.shape != (steps, store.hidden_size):
            raise VlaprobeError(
                f"store {path} layer {layer} has shape {h.shape}, expected ({steps}, {store.hidden_size}); the store is damaged, collect it again"
            )
        hidden[i] = h
    position, _ = store.step_index(keys)
    return ProbeData(
        hidden=torch.from_numpy(hidden),
        layers=layer_ids,
        labels={h: np.asarray(store.labels(h, keys), bool) for h in heads},
        atom_names={h: list(store.atom_names[h]) for h in heads},
        episode=np.asarray(position, np.int64),
        episode_keys=keys,
        episode_tasks=np.array([e.task for e in episodes], np.int64),
        model_id=store.model_id,
        pooling=store.pooling,
        num_hidden_states=store.num_hidden_states,
        suite=store.suite,
        defined={h: store.defined(h, keys) for h in heads},
    )


def synthetic_atom_names(num_object: int, num_action: int) -> dict[str, list[str]]:
    """Canonical-looking atom names cycling through the paper's predicates (for synthetic data)."""
    obj = [
        f"{p}(obj_{i},obj_{i + 1})"
        if p in ("behind", "in-front-of", "left-of", "right-of", "on", "inside")
        else f"{p}(obj_{i})"
        for i, p in ((i, OBJECT_PREDICATES[i % len(OBJECT_PREDICATES)]) for i in range(num_object))
    ]
    act = [f"{ACTION_PREDICATES[i % 2]}(obj_{i // 2})" for i in range(num_action)]
    return {"object": obj, "action": act}


def synthetic_data(
    num_tasks: int = 4,
    episodes_per_task: int = 6,
    steps_per_episode: int = 40,
    num_layers: int = 5,
    hidden_size: int = 64,
    num_object: int = 18,
    num_action: int = 4,
    constant_fraction: float = 0.3,
    label_noise: float = 0.05,
    signal: float = 3.0,
    outlier_dims: int = 2,
    seed: int = 0,
    dtype: torch.dtype = torch.float16,
) -> ProbeData:
    """Episodes with labels linearly encoded in the hidden states, the way a probe expects to find them.

    Labels: per task each atom is never true, always true, or true on one contiguous stretch of the
    episode (like a grasp); ``constant_fraction`` of the atoms are never true in any episode (the filter
    drops them). The observed labels then have ``label_noise`` of their entries flipped, so the best
    possible accuracy of any probe is ``1 - label_noise``. Hidden states: every layer adds
    ``signal * profile[layer]`` times each clean label (+-1/2) along a random unit direction to Gaussian
    noise of unit variance per dimension, a per-episode offset and a few large-variance "outlier" dimensions
    with no label information (like a language model's massive activations). The profile rises from 0.2
    at the first layer to 1 in the middle and falls to 0.6 at the last, so middle layers probe best.
    """
    rng = np.random.default_rng(seed)
    names = synthetic_atom_names(num_object, num_action)
    num_atoms = num_object + num_action
    num_episodes = num_tasks * episodes_per_task
    steps = num_episodes * steps_per_episode
    tasks = np.repeat(np.arange(num_tasks), episodes_per_task)

    kind = rng.choice(3, size=(num_tasks, num_atoms), p=[0.35, 0.1, 0.55])  # never / always / a stretch
    constant = rng.random(num_atoms) < constant_fraction
    kind[:, constant] = 0
    clean = np.zeros((steps, num_atoms), bool)
    t = np.arange(steps_per_episode)
    for e in range(num_episodes):
        rows = slice(e * steps_per_episode, (e + 1) * steps_per_episode)
        k = kind[tasks[e]]
        length = rng.integers(steps_per_episode // 5, 4 * steps_per_episode // 5, size=num_atoms)
        start = rng.integers(0, steps_per_episode - length + 1)
        stretch = (t[:, None] >= start) & (t[:, None] < start + length)
        clean[rows] = np.where(k == 1, True, np.where(k == 2, stretch, False))
    flips = rng.random(clean.shape) < label_noise
    flips[:, constant] = False  # keep never-true atoms exactly constant: the filter test relies on it
    observed = clean ^ flips

    profile = np.interp(np.arange(num_layers), [0, num_layers // 2, max(num_layers - 1, 1)], [0.2, 1.0, 0.6])
    episode = np.repeat(np.arange(num_episodes), steps_per_episode)
    hidden = torch.empty((num_layers, steps, hidden_size), dtype=dtype)
    g = torch.Generator().manual_seed(seed)
    centered = torch.from_numpy(clean.astype(np.float32) - 0.5)
    scale = torch.ones(hidden_size)
    scale[:outlier_dims] = 30.0
    for layer in range(num_layers):
        directions = torch.randn(num_atoms, hidden_size, generator=g)
        directions /= directions.norm(dim=1, keepdim=True)
        offsets = 0.5 * torch.randn(num_episodes, hidden_size, generator=g)
        x = torch.randn(steps, hidden_size, generator=g)
        x += offsets[torch.from_numpy(episode)]
        x *= scale
        x += (signal * float(profile[layer])) * (centered @ directions)
        hidden[layer] = x.to(dtype)
    return ProbeData(
        hidden=hidden,
        layers=list(range(num_layers)),
        labels={"object": observed[:, :num_object], "action": observed[:, num_object:]},
        atom_names=names,
        episode=episode,
        episode_keys=[f"t{tasks[e]:02d}_i{e:02d}_a00" for e in range(num_episodes)],
        episode_tasks=tasks,
        model_id="synthetic",
        pooling="last_prompt",
        num_hidden_states=num_layers,
    )
