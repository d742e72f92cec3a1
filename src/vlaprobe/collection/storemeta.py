"""The store's metadata: the root attributes of ``zarr.json``, validated (:func:`read_meta`) and typed
(:class:`StoreMeta`). ``docs/collection.md`` lists every key."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject

FORMAT = "vlaprobe-activations"
FORMAT_VERSION = 1


def read_json(path: Path) -> JsonObject:
    with open(path, "rb") as f:
        return json.load(f)


def read_meta(path: Path, hint: str = "pass the --out folder of a `vlaprobe collect` run") -> JsonObject:
    """The root attributes of a store, or a one-line error saying why ``path`` is not a readable store."""
    if not path.exists():
        raise VlaprobeError(f"no activation store at {path}: the folder does not exist; {hint}")
    if not path.is_dir():
        raise VlaprobeError(f"{path} is not an activation store: it is a file, not a folder; {hint}")
    try:
        root = read_json(path / "zarr.json")
    except (OSError, ValueError):
        raise VlaprobeError(f"{path} is not an activation store (no readable zarr.json); {hint}") from None
    meta = root.get("attributes") or {}
    if root.get("node_type") != "group" or meta.get("format") != FORMAT:
        raise VlaprobeError(f"{path} is not an activation store (no {FORMAT!r} metadata); {hint}")
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise VlaprobeError(
            f"{path} is an activation store of format_version {version}, this vlaprobe reads version "
            f"{FORMAT_VERSION}; collect it again with this version or use the vlaprobe that wrote it"
        )
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing or not isinstance(meta["atom_names"], dict):
        raise VlaprobeError(
            f"{path}/zarr.json lacks {', '.join(missing or ['atom_names as a mapping'])}: the store's metadata "
            "were edited or damaged; restore that file or collect the store again"
        )
    return meta


REQUIRED_META = ("atom_names", "model_id", "num_hidden_states", "hidden_size", "pooling")
"""Root attributes every reader needs."""


@dataclass(frozen=True)
class StoreMeta:
    """The store's metadata (the root attributes written by ``vlaprobe collect`` through
    :meth:`~vlaprobe.collection.writer.StoreWriter.open`), typed: what other packages read of it. Keys a store
    of this format version may lack (written before they existed) read as their defaults."""

    format_version: int
    model_id: str
    pooling: str
    num_hidden_states: int
    hidden_size: int
    atom_names: dict[str, list[str]]
    created: str = ""
    """When the store was created (ISO 8601; "" in stores that do not say)."""
    driver: str | None = None
    """Who acted: "policy", "expert", "dagger" (None: not recorded)."""
    instructions: dict[str, str] = field(default_factory=dict)
    """Task id (as a string) -> the task's instruction."""
    perturb: str | None = None
    """The perturbation spec of the run (None: no perturbation)."""
    suite: str = "libero_spatial"
    """The LIBERO suite the episodes come from (stores written before suites were recorded are LIBERO-spatial's)."""

    @classmethod
    def parse(cls, meta: Mapping[str, Json]) -> StoreMeta:
        """The typed view of root attributes :func:`read_meta` accepted."""
        return cls(
            format_version=int(meta["format_version"]),
            model_id=str(meta["model_id"]),
            pooling=str(meta["pooling"]),
            num_hidden_states=int(meta["num_hidden_states"]),
            hidden_size=int(meta["hidden_size"]),
            atom_names={str(h): [str(a) for a in v] for h, v in meta["atom_names"].items()},
            created=str(meta.get("created") or ""),
            driver=None if meta.get("driver") is None else str(meta["driver"]),
            instructions={str(k): str(v) for k, v in (meta.get("instructions") or {}).items()},
            perturb=None if meta.get("perturb") is None else str(meta["perturb"]),
            suite=str(meta.get("suite") or "libero_spatial"),
        )


def read_store_meta(path: str | Path) -> StoreMeta:
    """The typed metadata of the store at ``path``, or a one-line error (see :func:`read_meta`)."""
    return StoreMeta.parse(read_meta(Path(path)))
