"""The single writer of an activation store (``vlaprobe.collection.store`` reads it).

An episode is written into ``<store>/.staging/`` (same filesystem, outside the zarr hierarchy), fsync'd, and
published with one atomic ``os.rename`` into ``episodes/``: readers, and a rerun after ``kill -9``, see an
episode completely or not at all. The writer holds the store folder's lock (:mod:`vlaprobe.locks`), so it
may delete whatever a killed predecessor left in ``.staging/``.
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zarr

from vlaprobe.collection.store import (
    ATOM_ARRAYS,
    FORMAT,
    FORMAT_VERSION,
    EpisodeInfo,
    list_infos,
    read_meta,
)
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject, Setting, as_json, settings_difference
from vlaprobe.locks import FolderLock, lock_folder

STAGING = ".staging"
CHUNK_BYTES = 8 << 20
"""Target raw size of a chunk of the per-step arrays other than ``hidden`` (images: ~53 frames at 224²)."""
FSYNC_THREADS = 8
CHUNK_KEYS = {"name": "default", "separator": "."}
"""Chunk files named ``c.<i>.<j>...`` inside the array's folder: no nested folder per chunk dimension."""
LAYOUTS = "by suite, task, seed and sample index"
"""What a sampled layout is a function of (recorded under ``--inits sampled|sampled-swap``)."""
LAYOUTS_BEFORE = "by task and sample index"
"""... in stores written before the layouts depended on the seed (they cannot be resumed with this vlaprobe)."""
DEFINING = (
    Setting("model_id", "--model: the model id"),
    Setting("model", "--model: the model"),
    Setting("atom_names", "the atom vocabulary"),
    Setting("num_hidden_states", "--model: the number of hidden states"),
    Setting("hidden_size", "--model: the hidden size"),
    Setting("pooling", "--pooling"),
    Setting("driver", "--driver"),
    Setting("dagger_beta", "--dagger-beta", 0.0),
    Setting("expert_faults", "--expert-faults", ""),
    Setting("takeover", "--takeover and its settings", ""),
    Setting("suite", "--env.suite"),
    Setting("env", "--env"),
    Setting("seed", "--seed"),
    Setting("post_success_steps", "--post-success-steps", 0),
    Setting("inits", "--inits", "fixed"),
    Setting("layouts", "--inits: the layouts", LAYOUTS_BEFORE),
    Setting("perturb", "--perturb", ""),
    Setting("first_init", "--first-init", 0),
    Setting("keep_failed", "--keep-failed", False),
)
"""The settings that define a store's episodes, the one list (a run adds to a store only with the same values).
The model's entries are compared once the model is loaded; ``layouts`` only under sampled inits."""


# ----- writing --------------------------------------------------------------------------------------------------
def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(folder: Path) -> None:
    """Flush every file and folder under ``folder`` to disk.

    In parallel: the filesystem journal then commits them together (measured ~20x faster than one by one).
    """
    walk = list(os.walk(folder))
    paths = [Path(d) / f for d, _, files in walk for f in files] + [Path(d) for d, _, _ in walk]
    with ThreadPoolExecutor(FSYNC_THREADS) as pool:
        list(pool.map(_fsync, paths))


RECORDED_IN_CONFIG = ("first_init", "keep_failed")
"""Defining settings that stores written before they were recorded still hold in the creating run's ``config``."""


def check_compatible(path: Path, stored: Mapping[str, Json], meta: Mapping[str, Json]) -> None:
    """Refuse (one line, naming both values) a run whose :data:`DEFINING` settings differ from the store's."""
    config = stored.get("config")
    config = config if isinstance(config, dict) else {}
    recorded = {**{k: config[k] for k in RECORDED_IN_CONFIG if k in config}, **stored}
    found = settings_difference(DEFINING, recorded, meta, "store")
    if found:
        raise VlaprobeError(
            f"cannot add to store {path}: {found}; collect into another --out or rerun with the store's settings"
        )


def _chunks(name: str, shape: tuple[int, ...], itemsize: int) -> tuple[int, ...]:
    """``hidden``: one chunk per layer. Others: whole steps, ~CHUNK_BYTES per chunk, so an episode is a few files."""
    if name == "hidden":
        return (1, *(max(1, s) for s in shape[1:]))
    row = itemsize * int(np.prod(shape[1:], dtype=np.int64))
    steps = max(1, min(shape[0], CHUNK_BYTES // max(1, row)))
    return (steps, *(max(1, s) for s in shape[1:]))


@dataclass(frozen=True)
class StagedEpisode:
    """A completely written, flushed episode waiting in ``.staging/`` to be published or discarded."""

    info: EpisodeInfo
    path: Path


class StoreWriter:
    """The single writer of a store: creates it or checks that this run fits it, stages and publishes episodes.

    Use as a context manager; the store folder stays locked against other writers until :meth:`close`.
    """

    def __init__(self, path: Path, meta: JsonObject, lock: FolderLock | None) -> None:
        self.path = path
        self.meta = meta
        self._lock = lock
        self._staging = path / STAGING
        self._open = True

    @classmethod
    def open(cls, path: str | Path, meta: Mapping[str, Json], lock: FolderLock | None = None) -> StoreWriter:
        """Create the store with ``meta`` as its metadata, or open an existing compatible one.

        ``meta`` must hold every :data:`DEFINING` entry plus whatever else the store should record. ``lock``:
        the caller's lock on the store folder (:func:`vlaprobe.locks.lock_folder`); without one the writer takes
        it, and releases it on :meth:`close`. Leftovers of a killed writer (staged episodes, partial metadata
        files) are deleted.
        """
        path = Path(path)
        if path.exists() and not path.is_dir():
            raise VlaprobeError(f"--out {path} is a file, not a store folder; choose a folder path")
        own = lock_folder(path) if lock is None else None
        try:
            if not path.exists() or not any(path.iterdir()):
                cls._create(path, {**as_json(dict(meta)), "format": FORMAT, "format_version": FORMAT_VERSION})
            stored = read_meta(path, "choose a new or empty folder for --out, or an existing store")
            check_compatible(path, stored, meta)
            shutil.rmtree(path / STAGING, ignore_errors=True)
            for folder in (path, path / "episodes", path / "failures"):
                for leftover in folder.glob("*.partial"):  # zarr's own temp files of an interrupted write
                    leftover.unlink(missing_ok=True)
        except BaseException:
            if own is not None:
                own.release()
            raise
        return cls(path, stored, own)

    @staticmethod
    def _create(path: Path, meta: JsonObject) -> None:
        """Build the empty hierarchy beside ``path`` and rename it into place (a kill leaves no half store)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.parent / f".{path.name}.{uuid.uuid4().hex[:8]}.partial"
        meta = {**meta, "all_chunks_written": True}  # vlaprobe.collection.verify: a missing chunk is damage
        root = zarr.open_group(zarr.storage.LocalStore(tmp), mode="w-", attributes=meta)
        root.create_group("episodes")
        root.create_group("failures")
        _fsync_tree(tmp)
        try:
            os.rename(tmp, path)  # replaces an empty folder; fails if another writer created the store first
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not (path / "zarr.json").is_file():
                raise
        _fsync(path.parent)

    # ----- state ---------------------------------------------------------------------------------------------
    def outcomes(self) -> dict[str, EpisodeInfo]:
        """Every unit already decided: published episodes (successful or failed) and failure markers."""
        infos = list_infos(self.path / "failures") + list_infos(self.path / "episodes")
        return {e.key: e for e in infos}

    def update_meta(self, **fields: Json) -> None:
        """Set metadata fields (e.g. the list of runs); the root metadata file is replaced atomically."""
        self.meta = {**self.meta, **as_json(fields)}
        root = zarr.open_group(zarr.storage.LocalStore(self.path), mode="r+")
        root.attrs.put(self.meta)
        _fsync(self.path / "zarr.json")
        _fsync(self.path)

    # ----- episodes ------------------------------------------------------------------------------------------
    def _check(self, info: EpisodeInfo, arrays: Mapping[str, np.ndarray]) -> None:
        t, layers, size = info.length, self.meta["num_hidden_states"], self.meta["hidden_size"]
        if t < 1:
            raise ValueError(f"episode {info.key} has no steps")
        for name, a in arrays.items():
            if name != "hidden" and (a.ndim == 0 or a.shape[0] != t):
                raise ValueError(f"episode {info.key}: {name} has shape {a.shape}, expected {t} steps first")
        hidden = arrays["hidden"]
        if hidden.shape[:2] != (layers, t) or hidden.shape[-1] != size:
            raise ValueError(
                f"episode {info.key}: hidden has shape {hidden.shape}, expected ({layers}, {t}, ..., {size})"
            )
        for head, name in ATOM_ARRAYS.items():
            width = len(self.meta["atom_names"][head])
            if arrays[name].shape != (t, width):
                raise ValueError(
                    f"episode {info.key}: {name} has shape {arrays[name].shape}, expected ({t}, {width})"
                )

    def stage(
        self, info: EpisodeInfo, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Json] | None = None
    ) -> StagedEpisode:
        """Write an episode under ``.staging/`` and flush it to disk; nothing is visible yet.

        ``arrays`` must hold ``hidden`` (float16), ``object_atoms`` and ``action_atoms`` (bool) with the
        store's shapes; every other array has steps first. A ``/`` in a name makes a subgroup (``world/pos``).
        """
        self._check(info, arrays)
        self._staging.mkdir(exist_ok=True)
        tmp = self._staging / f"{info.key}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        group = zarr.open_group(
            zarr.storage.LocalStore(tmp), mode="w-", attributes=as_json({**(attrs or {}), **info.attrs()})
        )
        heads = {name: head for head, name in ATOM_ARRAYS.items()}
        for name, a in arrays.items():
            parent = group
            *folders, leaf = name.split("/")
            for folder in folders:
                parent = parent.require_group(folder)
            extra = {"atom_names": self.meta["atom_names"][heads[name]]} if name in heads else None
            parent.create_array(
                leaf,
                data=np.ascontiguousarray(a),
                chunks=_chunks(name, a.shape, a.dtype.itemsize),
                chunk_key_encoding=CHUNK_KEYS,  # type: ignore[arg-type]
                attributes=extra,
                config={"write_empty_chunks": True},  # type: ignore[arg-type]  # a chunk file per chunk: a missing one is damage
            )
        _fsync_tree(tmp)
        return StagedEpisode(info, tmp)

    def _move_in(self, staged: StagedEpisode, folder: str) -> None:
        target = self.path / folder / staged.info.key
        try:
            os.rename(staged.path, target)
        except OSError:
            self.discard(staged)
            if target.exists():
                raise VlaprobeError(f"store {self.path} already has {folder}/{staged.info.key}") from None
            raise
        _fsync(self.path / folder)

    def publish(self, staged: StagedEpisode) -> None:
        """Make a staged episode visible under ``episodes/`` (one atomic rename)."""
        self._move_in(staged, "episodes")

    def discard(self, staged: StagedEpisode) -> None:
        shutil.rmtree(staged.path, ignore_errors=True)

    def write_episode(
        self, info: EpisodeInfo, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Json] | None = None
    ) -> None:
        """Stage and publish in one go."""
        self.publish(self.stage(info, arrays, attrs))

    def mark_failed(self, info: EpisodeInfo, attrs: Mapping[str, Json] | None = None) -> None:
        """Record that a unit was tried and failed, without its data (so a resume does not try it again)."""
        self._staging.mkdir(exist_ok=True)
        tmp = self._staging / f"{info.key}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        zarr.open_group(
            zarr.storage.LocalStore(tmp), mode="w-", attributes=as_json({**(attrs or {}), **info.attrs()})
        )
        _fsync_tree(tmp)
        self._move_in(StagedEpisode(info, tmp), "failures")

    def close(self) -> None:
        """Delete what is still staged (never published) and release the lock if the writer took it."""
        if not self._open:
            return
        self._open = False
        shutil.rmtree(self._staging, ignore_errors=True)
        if self._lock is not None:
            self._lock.release()

    def __enter__(self) -> StoreWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
