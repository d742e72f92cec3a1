"""Damage checks of an activation store: what `vlaprobe info` names, `train` refuses and `collect` explains.

Zarr reads a missing chunk file as zeros and ``list_infos`` skips a group it cannot read, so a deleted
chunk, an episode folder without its metadata or metadata edited by hand would otherwise pass silently.
:func:`check_store` looks at every episode's metadata and lists its chunk files (cheap: no array data is
read); with ``read=True`` it also decodes every chunk (finds truncated or corrupted files).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable
from dataclasses import dataclass
from itertools import product
from pathlib import Path

import numpy as np

from vlaprobe.collection.store import ATOM_ARRAYS, array_at, read_meta
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject

REQUIRED = ("hidden", *ATOM_ARRAYS.values())
"""Arrays every episode must have."""
ALL_CHUNKS_KEY = "all_chunks_written"
"""Root metadata flag: every chunk of every array has a file (even one equal to the fill value)."""


@dataclass(frozen=True)
class Damage:
    """One damaged episode (or foreign folder) under ``episodes/`` and what is wrong with it."""

    key: str
    """The episode folder's name."""
    problem: str
    """What is wrong, e.g. "hidden: chunk file c.12.0.0 missing"."""


def _json(path: Path) -> JsonObject:
    with open(path, "rb") as f:
        data = json.load(f)
    if not isinstance(data, dict):
        raise ValueError("not a JSON object")
    return data


def _arrays(group: Path) -> dict[str, Path]:
    """Array name ("hidden", "world/pos") -> folder, for every array folder under an episode group."""
    out = {}
    for folder, subdirs, files in os.walk(group):
        subdirs[:] = [d for d in subdirs if not d.startswith(".")]
        rel = Path(folder).relative_to(group)
        if rel.parts and "zarr.json" in files:
            try:
                node = _json(Path(folder) / "zarr.json").get("node_type")
            except (OSError, ValueError):
                node = "array"  # unreadable: reported as an array with bad metadata
            if node == "array":
                out["/".join(rel.parts)] = Path(folder)
                subdirs[:] = []
        elif rel.parts and not any(Path(folder, d, "zarr.json").exists() for d in subdirs):
            out["/".join(rel.parts)] = Path(folder)  # a folder whose metadata file was deleted
    return out


def _chunk_names(meta: JsonObject) -> list[str]:
    shape = meta["shape"]
    chunks = meta["chunk_grid"]["configuration"]["chunk_shape"]
    encoding = meta.get("chunk_key_encoding", {})
    sep = encoding.get("configuration", {}).get("separator", "/")
    prefix = "c" + sep if encoding.get("name", "default") == "default" else ""
    grid = [range(math.ceil(s / c)) if c else range(0) for s, c in zip(shape, chunks, strict=True)]
    if encoding.get("name", "default") == "v2":
        return [sep.join(map(str, idx)) or "0" for idx in product(*grid)]
    return [prefix + sep.join(map(str, idx)) for idx in product(*grid)]


def _check_array(name: str, folder: Path, all_chunks: bool) -> tuple[tuple[int, ...] | None, str | None]:
    """The array's shape from its metadata and the first problem found (None if it looks whole)."""
    try:
        meta = _json(folder / "zarr.json")
        shape = tuple(int(s) for s in meta["shape"])
        names = _chunk_names(meta)
    except FileNotFoundError:
        return None, f"{name}: array metadata (zarr.json) missing"
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return None, f"{name}: array metadata unreadable ({type(exc).__name__})"
    if name == "hidden" or all_chunks:
        for chunk in names:
            path = folder / chunk
            try:
                if path.stat().st_size == 0:
                    return shape, f"{name}: chunk file {chunk} is empty"
            except FileNotFoundError:
                return shape, f"{name}: chunk file {chunk} missing"
    return shape, None


def _check_episode(group: Path, meta: JsonObject) -> tuple[str | None, set[str]]:
    """The first problem of one episode group (None if none) and its array names."""
    try:
        attrs = _json(group / "zarr.json").get("attributes") or {}
        length = int(attrs["length"])
    except FileNotFoundError:
        return "episode metadata (zarr.json) missing", set()
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"episode metadata unreadable ({type(exc).__name__})", set()
    all_chunks = bool(meta.get(ALL_CHUNKS_KEY))
    arrays = _arrays(group)
    missing = [a for a in REQUIRED if a not in arrays]
    if missing:
        return f"array(s) {', '.join(missing)} missing", set(arrays)
    layers, size = int(meta["num_hidden_states"]), int(meta["hidden_size"])
    for name, folder in sorted(arrays.items()):
        shape, problem = _check_array(name, folder, all_chunks)
        if problem:
            return problem, set(arrays)
        assert shape is not None
        if name == "hidden":
            if shape[:2] != (layers, length) or shape[-1] != size:
                return (
                    f"hidden has shape {shape}, but the metadata say {layers} hidden states x {length} steps "
                    f"x {size}",
                    set(arrays),
                )
        elif not shape or shape[0] != length:
            return f"{name} has {shape[0] if shape else 0} steps, the episode metadata say {length}", set(
                arrays
            )
        head = {v: k for k, v in ATOM_ARRAYS.items()}.get(name)
        if head is not None and shape[1:] != (len(meta["atom_names"][head]),):
            return f"{name} has {shape[1:]} atoms, the store lists {len(meta['atom_names'][head])}", set(
                arrays
            )
    return None, set(arrays)


def _read_all(path: Path, key: str, names: set[str]) -> str | None:
    """Decode every chunk of an episode's arrays; the first failure, or None."""
    import zarr

    root = zarr.open_group(zarr.storage.LocalStore(path, read_only=True), mode="r")
    for name in sorted(names):
        try:
            np.asarray(array_at(root, f"episodes/{key}/{name}")[...])
        except Exception as exc:  # zstd/blosc/JSON errors of a damaged file: any of them means damage
            return f"{name}: cannot be read ({type(exc).__name__}: {str(exc)[:80]})"
    return None


def check_store(path: str | Path, read: bool = False, keys: Iterable[str] | None = None) -> list[Damage]:
    """Every damaged episode of the store at ``path`` (an empty list: none found).

    Checks each folder under ``episodes/``: its metadata, the presence and shapes of its arrays against the
    episode's length and the store's metadata, and that every chunk file of ``hidden`` (of every array for
    stores that write all chunks) exists. ``read`` also decodes every array: in older stores (no
    ``all_chunks_written``) it is the only check that finds a truncated chunk of an array other than
    ``hidden``, and a missing one there is not found at all (zarr reads it as the fill value). ``keys``: decode
    only these episodes (the ones a command is about to read); the cheap checks still cover every episode.
    """
    path = Path(path)
    wanted = None if keys is None else set(keys)
    meta = read_meta(path)
    folder = path / "episodes"
    entries = (
        sorted((e for e in os.scandir(folder) if not e.name.startswith(".")), key=lambda e: e.name)
        if folder.is_dir()
        else []
    )
    found: dict[str, tuple[str | None, set[str]]] = {}
    for entry in entries:
        if not entry.is_dir():
            continue  # the group's zarr.json (files are not episodes)
        found[entry.name] = _check_episode(Path(entry.path), meta)
    # Arrays that most episodes have are expected in all (a deleted image/ or world/pos is damage too).
    counts: dict[str, int] = {}
    for _, names in found.values():
        for n in names:
            counts[n] = counts.get(n, 0) + 1
    common = {n for n, c in counts.items() if 2 * c > len(found)}
    damage = []
    for entry in entries:
        if entry.name not in found:
            continue
        problem, names = found[entry.name]
        if problem is None and common - names:
            problem = f"array(s) {', '.join(sorted(common - names))} missing"
        if problem is None and read and (wanted is None or entry.name in wanted):
            problem = _read_all(path, entry.name, names)
        if problem is not None:
            damage.append(Damage(entry.name, problem))
    return damage


def describe(path: str | Path, damage: list[Damage], limit: int = 3) -> str:
    """One line naming the damaged episodes (the first ``limit`` with their problem)."""
    shown = "; ".join(f"{d.key}: {d.problem}" for d in damage[:limit])
    more = f" (and {len(damage) - limit} more)" if len(damage) > limit else ""
    return f"store {path} has {len(damage)} damaged episode(s): {shown}{more}"


def repair_hint(path: str | Path, damage: list[Damage]) -> str:
    """How to drop the damaged episodes so that `vlaprobe collect` records them again."""
    folders = " ".join(str(Path(path) / "episodes" / d.key) for d in damage[:3])
    more = " ..." if len(damage) > 3 else ""
    return f"delete them (rm -r {folders}{more}) and rerun `vlaprobe collect` with the same settings to record them again"


def require_intact(path: str | Path, read: bool = False, keys: Iterable[str] | None = None) -> None:
    """Raise a one-line :class:`VlaprobeError` naming the damaged episodes and the repair, if any (``read``,
    ``keys``: as :func:`check_store`; `cognition` and `serve --store` decode the episodes they read)."""
    damage = check_store(path, read=read, keys=keys)
    if damage:
        raise VlaprobeError(f"{describe(path, damage)}; {repair_hint(path, damage)}")
