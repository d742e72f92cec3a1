"""Small shared file helpers: atomic writes, the package versions recorded with every output, JSON types."""

from __future__ import annotations

import json
import os
import sys
import tempfile
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any, TypeAlias, TypeVar

import dacite

from vlaprobe.errors import VlaprobeError

Json: TypeAlias = Any
"""A JSON value as ``json.loads`` returns it (object, list, string, number, bool, null). Only at the edges: files
of a store, a run or a checkpoint, config files and the wire; what one package hands another is a dataclass."""
JsonObject: TypeAlias = dict[str, Json]
"""A JSON object (a file's metadata, a config written as JSON, a record of a metrics log)."""

# Packages whose versions shape recorded data, probes and reports.
VERSIONED = ("torch", "numpy", "zarr", "mujoco", "robosuite", "libero", "transformers", "ray")


def _file_mode() -> int:
    """Permissions of a newly created file under the current umask (mkstemp would leave 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def write_atomic(
    path: str | Path, data: bytes | str | Callable[[str], object], mode: int | None = None
) -> None:
    """Write ``path`` under a temporary name in the same folder, then rename it into place.

    ``data`` is the content, or a function that writes the file whose path it is given (e.g. safetensors'
    ``save_file``). A reader never sees a half-written file; a failure leaves no temporary behind. ``mode``:
    the file's permissions (default: as a new file under the umask).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            if not callable(data):
                f.write(data.encode() if isinstance(data, str) else data)
        if callable(data):
            data(tmp)
        os.chmod(tmp, _file_mode() if mode is None else mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def versions() -> dict[str, str | None]:
    """Installed versions of vlaprobe, Python and the packages in ``VERSIONED`` (None: not installed)."""
    import vlaprobe

    out: dict[str, str | None] = {"vlaprobe": vlaprobe.__version__, "python": sys.version.split()[0]}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def check_output_folder(out: str | Path, flag: str = "--out") -> None:
    """Refuse (one line, before any long work) an output folder that cannot be written.

    ``out`` may not exist yet: then its nearest existing parent must be a folder in which a file can be
    created (a file in the way, a read-only folder or ``/proc`` fail here, not after hours of work).
    """
    from vlaprobe.errors import VlaprobeError

    out = Path(out)
    if str(out) in ("", "."):
        raise VlaprobeError(
            f"{flag} needs a folder path (got {str(out)!r}); name a new folder, e.g. {flag} runs/mine"
        )
    if out.exists() and not out.is_dir():
        raise VlaprobeError(f"{flag} {out} is a file, not a folder; choose a folder path")
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise VlaprobeError(f"{flag} {out}: {parent} is a file, not a folder; choose another path")
    try:
        fd, probe = tempfile.mkstemp(dir=parent, prefix=".vlaprobe-write-check.")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise VlaprobeError(
            f"{flag} {out}: cannot write in {parent} ({exc.strerror}); choose a writable folder"
        ) from None


# -- output folders a command owns ------------------------------------------------------------------------
OWNER_FILE = ".vlaprobe-owner"
"""Marker that ``report`` and ``run`` leave in their output folder: the command's name. ``train``'s folder is
recognised by its ``probes.json`` instead (a file of its own format)."""


@dataclass(frozen=True)
class FolderKind:
    """What one command's output folder holds, for :func:`check_owned_folder`."""

    owner: str
    """The command that writes it ("train", "report", "run"): the marker's content."""
    known: Callable[[str], bool] = lambda name: True
    """Names (not starting with ".") the command writes there; others are refused even in its own folder."""
    signature: Callable[[Path], bool] = lambda folder: False
    """Recognises the command's folder without a marker: its own file format (``probes.json``), or a folder
    written before markers existed."""
    fix: str = "choose an empty or new folder"


def folder_owner(out: Path) -> str | None:
    """The command named by ``out``'s marker (None: no readable marker)."""
    try:
        return (out / OWNER_FILE).read_text(encoding="utf-8").strip() or None
    except (OSError, UnicodeDecodeError):
        return None


def check_owned_folder(out: str | Path, kind: FolderKind, flag: str = "--out") -> None:
    """Refuse (one line, before any work) an ``out`` that cannot be written or holds files ``kind.owner`` did
    not write: a folder with files is the command's only when its marker (or ``kind.signature``) says so, and
    then only if every file is one the command writes. The one check of ``train``, ``report`` and ``run``."""
    from vlaprobe.errors import VlaprobeError

    out = Path(out)
    check_output_folder(out, flag)
    if not out.is_dir():
        return
    names = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    if not names:
        return
    owner = folder_owner(out)
    ours = owner == kind.owner or (owner is None and kind.signature(out))
    foreign = [n for n in names if not kind.known(n)] if ours else names
    if foreign:
        shown = ", ".join(foreign[:4]) + (", ..." if len(foreign) > 4 else "")
        raise VlaprobeError(
            f"{flag} {out} holds files `vlaprobe {kind.owner}` did not write ({shown}); {kind.fix}"
        )


def mark_folder(out: str | Path, owner: str) -> None:
    """Leave ``owner``'s marker in ``out`` (created if needed): the folder is the command's from now on."""
    write_atomic(Path(out) / OWNER_FILE, owner + "\n")


# -- the settings that define an output, compared when a run adds to one ------------------------------------
@dataclass(frozen=True)
class Setting:
    """One setting that defines what an output folder holds: a run that adds to the folder must share it."""

    key: str
    """Its key in the folder's recorded settings (a store's metadata, a run's settings file)."""
    label: str
    """How the one-line refusal names it: the flag that sets it ("--perturb"), or what it is."""
    default: Json = None
    """Its value in folders written before it was recorded (None: it has always been recorded)."""


def _short(value: Json) -> str:
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


def json_difference(old: Json, new: Json, where: str = "") -> tuple[str, Json, Json] | None:
    """The first path below ``where`` at which two JSON values differ, with both values there; None if equal."""
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new), key=str):
            found = json_difference(old.get(k), new.get(k), f"{where}.{k}")
            if found:
                return found
        return None
    if isinstance(old, list | tuple) and isinstance(new, list | tuple) and len(old) == len(new):
        for i, (a, b) in enumerate(zip(old, new, strict=True)):
            found = json_difference(a, b, f"{where}[{i}]")
            if found:
                return found
        return None
    return None if old == new else (where, old, new)


def as_json(value: object) -> Json:
    """``value`` as it reads back from JSON (tuples become lists...), so comparisons are like for like."""
    return json.loads(json.dumps(value, default=str))


def settings_difference(
    settings: Collection[Setting], recorded: Mapping[str, Json], now: Mapping[str, Json], folder: str
) -> str | None:
    """The first of ``settings`` in which this run (``now``) differs from what ``folder`` recorded, as
    "LABEL is A in the FOLDER but B in this run"; None when they all agree. A setting without a default is
    compared only when ``now`` has it (a caller may check before it knows every value)."""
    for s in settings:
        if s.key not in now and s.default is None:
            continue
        found = json_difference(recorded.get(s.key, s.default), as_json(now.get(s.key, s.default)))
        if found:
            path, old, new = found
            label = s.label + (path.replace("_", "-") if s.label.startswith("--") else path)
            return f"{label} is {_short(old)} in the {folder} but {_short(new)} in this run"
    return None


T = TypeVar("T")


def read_versioned(
    path: Path, fmt: str, what: str, versions: Collection[int], hint: str, unversioned: int | None = None
) -> tuple[JsonObject, int]:
    """The JSON object of one of vlaprobe's versioned files and its format version, or a one-line error.

    ``fmt`` is the file's ``format`` and ``versions`` the ``format_version`` values this vlaprobe reads;
    ``unversioned`` is the version of a file written before it carried ``format``/``format_version`` (None:
    such a file is refused). The object is returned as it was read, ``format`` keys included.
    """
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise VlaprobeError(f"no {path}; {hint}") from None
    except (OSError, ValueError) as exc:
        raise VlaprobeError(f"cannot read {path}: {exc}; {hint}") from None
    unversioned_format = fmt if unversioned is not None else None
    if not isinstance(data, dict) or data.get("format", unversioned_format) != fmt:
        raise VlaprobeError(f"{path} is not a vlaprobe {what}; {hint}")
    version = data.get("format_version", unversioned)
    if not isinstance(version, int) or version not in versions:
        reads = ", ".join(str(v) for v in sorted(versions))
        raise VlaprobeError(
            f"{path} is a vlaprobe {what} of format version {version}, this vlaprobe reads version(s) {reads}; "
            f"{hint}"
        )
    return data, version


def from_json(
    cls: type[T], data: JsonObject, path: Path, hint: str, config: dacite.Config | None = None
) -> T:
    """``cls`` built from a file's JSON object (dacite), or a one-line error naming the damaged file."""
    try:
        return dacite.from_dict(cls, data, config=config or dacite.Config(check_types=False))
    except (dacite.DaciteError, TypeError, ValueError, KeyError, AttributeError) as exc:
        raise VlaprobeError(f"{path} is damaged ({exc}); {hint}") from None
