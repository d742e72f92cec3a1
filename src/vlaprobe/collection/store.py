"""The activation store: per-step hidden states, symbolic labels and observations of complete episodes.

A store is one folder holding a zarr (format 3) hierarchy that any zarr reader opens without this package
(``docs/collection.md`` is the full specification)::

    <store>/zarr.json              root group; its attributes are the store's metadata (``meta``)
    <store>/episodes/<key>/        one group per complete episode, key "t03_i12_a00" (task, init, attempt)
        hidden                     float16 (layers, T, hidden) or (layers, T, 7, hidden); one chunk per layer
        object_atoms, action_atoms bool (T, atoms), names in the array's attributes and in ``meta``
        image, proprio, action, predicted_action, action_tokens, step, world/* ...
                                   (the columns of ``collection.episode.EpisodeSteps``; group attributes:
                                   ``EpisodeInfo`` + ``EpisodeAttrs``)
    <store>/failures/<key>/        attributes only: a tried unit whose failed episode was not kept

This module reads (:class:`ActivationStore`); only :class:`~vlaprobe.collection.writer.StoreWriter` writes,
publishing each episode atomically (see ``vlaprobe.collection.writer``).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from types import EllipsisType

import numpy as np
import zarr
from numpy.typing import DTypeLike

from vlaprobe.collection.defined import ATTR, defined_rows, undefined_counts
from vlaprobe.collection.episode import EpisodeAttrs, EpisodeSteps, stored_records
from vlaprobe.collection.storemeta import (
    FORMAT,
    FORMAT_VERSION,
    REQUIRED_META,
    StoreMeta,
    read_json,
    read_meta,
    read_store_meta,
)
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject
from vlaprobe.rollout import StepRecord

ATOM_ARRAYS = {"object": "object_atoms", "action": "action_atoms"}

__all__ = [
    "ATOM_ARRAYS",
    "FORMAT",
    "FORMAT_VERSION",
    "REQUIRED_META",
    "ActivationStore",
    "EpisodeInfo",
    "StoreMeta",
    "StoredEpisode",
    "episode_key",
    "list_infos",
    "read_meta",
    "read_store_meta",
]
"""The metadata's names are defined in :mod:`vlaprobe.collection.storemeta` and importable from here too."""

SUMMARY_FIELDS = ("key", "task", "init", "attempt", "success", "length", "success_step")
"""Episode fields listed by :meth:`ActivationStore.summary` (``vlaprobe info --json``)."""


def episode_key(task: int, init: int, attempt: int = 0) -> str:
    """The unique name of an episode: ``t03_i12_a00``. Key order equals (task, init, attempt) order below 100."""
    return f"t{task:02d}_i{init:02d}_a{attempt:02d}"


def _success_step(attrs: Mapping[str, Json]) -> int | None:
    if "success_step" in attrs:
        return None if attrs["success_step"] is None else int(attrs["success_step"])
    return int(attrs["length"]) - 1 if attrs["success"] else None  # written before post_success_steps


@dataclass(frozen=True)
class EpisodeInfo:
    """What identifies and summarises one episode (the attributes of its group)."""

    key: str
    """Unique in a store, e.g. ``t03_i12_a00`` (task, init state, attempt)."""
    task: int
    """Task index in the suite."""
    init: int
    """Index of the task's fixed initial state."""
    attempt: int
    """Attempt number for this (task, init); 0 unless a driver retries."""
    success: bool
    """Whether the task's goal was reached."""
    length: int
    """Number of recorded steps."""
    seed: int
    """Seed the episode ran with."""
    driver: str
    """Who acted: ``"expert"`` or ``"policy"``."""
    success_step: int | None = None
    """Row of the first observation where the task succeeded (None if it never did); rows after it were
    recorded with ``post_success_steps``. Stores written before it existed: the last row of a successful
    episode."""

    def attrs(self) -> JsonObject:
        return asdict(self)

    @classmethod
    def from_attrs(cls, attrs: Mapping[str, Json]) -> EpisodeInfo:
        return cls(
            key=str(attrs["key"]),
            task=int(attrs["task"]),
            init=int(attrs["init"]),
            attempt=int(attrs["attempt"]),
            success=bool(attrs["success"]),
            length=int(attrs["length"]),
            seed=int(attrs["seed"]),
            driver=str(attrs["driver"]),
            success_step=_success_step(attrs),
        )

    @property
    def order(self) -> tuple[int, int, int]:
        return (self.task, self.init, self.attempt)


# ----- reading --------------------------------------------------------------------------------------------------
def list_infos(folder: Path) -> list[EpisodeInfo]:
    """Infos of the episode groups directly under ``folder``, in (task, init, attempt) order."""
    if not folder.is_dir():
        return []
    infos = []
    for entry in os.scandir(folder):
        if entry.name.startswith(".") or not entry.is_dir():
            continue
        try:
            attrs = read_json(Path(entry.path) / "zarr.json").get("attributes") or {}
            infos.append(EpisodeInfo.from_attrs(attrs))
        except (OSError, ValueError, KeyError):
            continue  # not an episode group: something foreign in the folder
    return sorted(infos, key=lambda e: e.order)


def array_at(group: zarr.Group, path: str) -> zarr.Array:
    """The array at ``path`` under ``group`` (a group there means a damaged store)."""
    node = group[path]
    if not isinstance(node, zarr.Array):
        raise VlaprobeError(
            f"{path} in the store is a group, not an array; the store is damaged: re-collect it"
        )
    return node


def group_at(group: zarr.Group, path: str) -> zarr.Group:
    """The group at ``path`` under ``group`` (an array there means a damaged store)."""
    node = group[path]
    if not isinstance(node, zarr.Group):
        raise VlaprobeError(
            f"{path} in the store is an array, not a group; the store is damaged: re-collect it"
        )
    return node


class StoredEpisode(Mapping[str, np.ndarray]):
    """One stored episode: its arrays by name (``"hidden"``, ``"image"``, ``"world/pos"``...), each read on first
    access, and the typed schema (:attr:`info`, :attr:`attributes`, :meth:`steps`, :meth:`records`)."""

    def __init__(self, group: zarr.Group) -> None:
        self._group = group
        self._names = sorted(name for name, _ in group.arrays()) + sorted(
            f"{g}/{name}" for g, sub in group.groups() for name, _ in sub.arrays()
        )
        self._cache: dict[str, np.ndarray] = {}

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._cache:
            if name not in self._names:
                raise KeyError(name)
            try:
                self._cache[name] = np.asarray(array_at(self._group, name)[...])
            except Exception as exc:  # a truncated chunk or bad array metadata: zarr's errors vary
                raise VlaprobeError(
                    f"episode {self._group.path} is damaged ({name}: {type(exc).__name__}); see `vlaprobe info "
                    "--verify STORE`, delete the episode folder and rerun `vlaprobe collect`"
                ) from None
        return self._cache[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    @property
    def attrs(self) -> JsonObject:
        """The episode group's attributes as stored JSON (the :class:`EpisodeInfo` fields, instruction, scene...)."""
        return dict(self._group.attrs)

    @property
    def info(self) -> EpisodeInfo:
        return EpisodeInfo.from_attrs(self._group.attrs)

    @property
    def attributes(self) -> EpisodeAttrs:
        """The episode's attributes besides :attr:`info`, typed."""
        return EpisodeAttrs.from_json(self._group.attrs)

    def steps(self) -> EpisodeSteps:
        """Every per-step column (reads them all)."""
        return EpisodeSteps.from_arrays(self)

    def records(self) -> Iterator[StepRecord]:
        """The rows as the step loop's :class:`~vlaprobe.rollout.StepRecord` (what is not stored is None)."""
        return stored_records(self, self.info.success_step)


EpisodeArrays = StoredEpisode
"""The name of :class:`StoredEpisode` before the typed schema."""


class ActivationStore:
    """Read-only view of a store: the episodes complete when it was opened, read one layer at a time."""

    def __init__(self, path: Path, meta: JsonObject) -> None:
        self.path = path
        self.meta = meta
        """The root attributes as stored (what the writer compares); read them through :attr:`metadata`."""
        self.metadata = StoreMeta.parse(meta)
        self.num_hidden_states: int = self.metadata.num_hidden_states
        self.hidden_size: int = self.metadata.hidden_size
        self.pooling: str = self.metadata.pooling
        self.model_id: str = self.metadata.model_id
        self.suite: str = self.metadata.suite
        self.created: str = self.metadata.created
        """When the store was created (ISO 8601; "" in stores that do not say)."""
        self.atom_names: dict[str, list[str]] = {h: list(v) for h, v in self.metadata.atom_names.items()}
        self._infos = list_infos(path / "episodes")
        self._by_key = {e.key: e for e in self._infos}
        self._root = zarr.open_group(zarr.storage.LocalStore(path, read_only=True), mode="r")
        self._arrays: dict[tuple[str, str], zarr.Array] = {}

    @classmethod
    def open(cls, path: str | Path) -> ActivationStore:
        """Open a store for reading; a one-line :class:`VlaprobeError` if it is not one or too new/old."""
        path = Path(path)
        return cls(path, read_meta(path))

    def episodes(self, success_only: bool = False) -> list[EpisodeInfo]:
        """Complete episodes, sorted by key."""
        return [e for e in self._infos if e.success or not success_only]

    def _resolve(self, episodes: Sequence[str] | None) -> list[EpisodeInfo]:
        if episodes is None:
            return list(self._infos)
        if isinstance(episodes, str):
            raise TypeError("episodes must be a sequence of keys, not one key")
        missing = [k for k in episodes if k not in self._by_key]
        if missing:
            raise VlaprobeError(
                f"store {self.path} has no episode {missing[0]!r}; list its episodes with `vlaprobe info {self.path}`"
            )
        return [self._by_key[k] for k in episodes]

    def _array(self, key: str, name: str) -> zarr.Array:
        if (key, name) not in self._arrays:
            self._arrays[key, name] = array_at(self._root, f"episodes/{key}/{name}")
        return self._arrays[key, name]

    def _concat(
        self,
        infos: list[EpisodeInfo],
        name: str,
        index: int | EllipsisType,
        trailing: tuple[int, ...],
        dtype: DTypeLike,
    ) -> np.ndarray:
        """``array[index]`` of every episode, stacked along steps into one preallocated matrix."""
        out = np.empty((sum(e.length for e in infos), *trailing), dtype=dtype)
        row = 0
        for e in infos:
            try:
                out[row : row + e.length] = self._array(e.key, name)[index]
            except VlaprobeError:
                raise
            except Exception as exc:  # a truncated chunk, deleted array or bad metadata: zarr's errors vary
                raise VlaprobeError(
                    f"store {self.path}: episode {e.key} is damaged ({name}: {type(exc).__name__}); see "
                    f"`vlaprobe info --verify {self.path}`, delete the episode folder and rerun `vlaprobe collect`"
                ) from None
            row += e.length
        return out

    def layer(self, layer: int, episodes: Sequence[str] | None = None) -> np.ndarray:
        """float16 (steps, hidden) of hidden state ``layer`` ((steps, 7, hidden) for pooling "action_tokens").

        Rows follow ``episodes`` (default: :meth:`episodes` order), steps in time order. Reads one chunk
        per episode: that layer's.
        """
        if not 0 <= layer < self.num_hidden_states:
            raise VlaprobeError(
                f"hidden state {layer} does not exist; store {self.path} has 0..{self.num_hidden_states - 1}"
            )
        infos = self._resolve(episodes)
        trailing = (7, self.hidden_size) if self.pooling == "action_tokens" else (self.hidden_size,)
        return self._concat(infos, "hidden", layer, trailing, np.float16)

    def labels(self, head: str, episodes: Sequence[str] | None = None) -> np.ndarray:
        """bool (steps, atoms) of one label head ("object" or "action"), columns in ``atom_names[head]`` order."""
        if head not in self.atom_names:
            raise VlaprobeError(
                f"store {self.path} has no label head {head!r}; it has {list(self.atom_names)}"
            )
        infos = self._resolve(episodes)
        return self._concat(infos, ATOM_ARRAYS[head], Ellipsis, (len(self.atom_names[head]),), bool)

    def defined(self, head: str, episodes: Sequence[str] | None = None) -> np.ndarray:
        """bool (steps, atoms) aligned with :meth:`labels`: False where the atom is undefined in that episode."""
        self.labels(head, [])  # the head check
        infos = self._resolve(episodes)
        return defined_rows(self._attrs(infos), [e.length for e in infos], self.atom_names, head)

    def _attrs(self, infos: list[EpisodeInfo]) -> list[JsonObject]:
        return [dict(group_at(self._root, f"episodes/{e.key}").attrs) for e in infos]

    def records_defined(self, episodes: Sequence[str] | None = None) -> bool:
        """Whether any of ``episodes`` carries the ``atoms_defined`` attribute (a union store)."""
        return any(ATTR in a for a in self._attrs(self._resolve(episodes)))

    def undefined(self) -> dict[str, tuple[int, int]]:
        """Head -> (atoms undefined in some episode, episodes leaving some atom undefined); (0, 0) everywhere
        in a single-vocabulary store."""
        return undefined_counts(self._attrs(self._infos), self.atom_names)

    def step_index(self, episodes: Sequence[str] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per row of :meth:`layer`: (position of its episode in ``episodes``, its step), both int32."""
        infos = self._resolve(episodes)
        lengths = [e.length for e in infos]
        position = np.repeat(np.arange(len(infos), dtype=np.int32), lengths)
        step = np.concatenate([np.arange(n, dtype=np.int32) for n in lengths]) if infos else position.copy()
        return position, step

    def episode(self, key: str) -> StoredEpisode:
        """One episode: its arrays (each read when first accessed) and its typed schema."""
        self._resolve([key])
        return StoredEpisode(group_at(self._root, f"episodes/{key}"))

    def iter_episodes(
        self, success_only: bool = False, episodes: Sequence[str] | None = None
    ) -> Iterator[tuple[EpisodeInfo, StoredEpisode]]:
        """One episode at a time (lazily read), never the whole store in memory."""
        infos = self._resolve(episodes) if episodes is not None else self.episodes(success_only)
        for info in infos:
            if info.success or not success_only:
                yield info, StoredEpisode(group_at(self._root, f"episodes/{info.key}"))

    def failures(self) -> list[EpisodeInfo]:
        """Tried units whose failed episode was not kept (their markers)."""
        return list_infos(self.path / "failures")

    def summary(self) -> JsonObject:
        """What ``vlaprobe info --json`` prints."""
        eps = self.episodes()
        return {
            "path": str(self.path),
            "format_version": self.metadata.format_version,
            "model_id": self.model_id,
            "driver": self.metadata.driver,
            "layers": self.num_hidden_states,
            "hidden_size": self.hidden_size,
            "pooling": self.pooling,
            "atoms": {h: len(v) for h, v in self.atom_names.items()},
            "steps": sum(e.length for e in eps),
            "episodes": [{k: getattr(e, k) for k in SUMMARY_FIELDS} for e in eps],
            "failures": [e.key for e in self.failures()],
        }
