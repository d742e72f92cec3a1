"""The output folder of ``vlaprobe train`` as one unit: checked up front, locked, replaced whole.

A probe folder's files (``probes.json``, ``probes.safetensors``, ``evaluation.json``, ``config.json``) are
written into a fresh hidden sibling folder and swapped in with renames, so a kill at any moment leaves either
the old folder or the new one, never a mix; leftovers of a killed run are removed by the next one. A folder
holding anything else (an activation store, a run folder, a model) is refused before any work, and the
folder's lock (:mod:`vlaprobe.locks`) keeps two trainings from writing it at once.
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import FolderKind, check_owned_folder
from vlaprobe.locks import lock_folder

if TYPE_CHECKING:
    from vlaprobe.probes.data import ProbeData

PROBE_FILES = frozenset(
    {"probes.json", "probes.safetensors", "evaluation.json", "config.json", "monitor.json", "hypotheses.json"}
)
"""What a probe folder holds (``monitor.json`` is written there by ``vlaprobe cognition``, ``hypotheses.json``
by ``vlaprobe hypotheses``; a new training replaces the folder whole, so neither outlives the probes it read)."""


PROBES_FOLDER = FolderKind(
    "train",
    known=lambda name: name in PROBE_FILES,
    signature=lambda folder: (folder / "probes.json").is_file(),
    fix="choose an empty folder or an earlier probes folder (e.g. RUN/probes, not the run or store folder)",
)
"""A probe folder, recognised by its ``probes.json`` (:func:`vlaprobe.files.check_owned_folder`, the mechanism
``report`` and ``run`` share; they leave a marker file as they have no file of their own format)."""


def check_probe_folder(out: Path, flag: str = "--out") -> None:
    """Refuse (one line) an ``out`` that is a file, cannot be created, or holds more than a probe folder."""
    check_owned_folder(out, PROBES_FOLDER, flag)


def _leftovers(out: Path) -> list[Path]:
    return sorted(out.parent.glob(f".{out.name}.*.partial")) + sorted(out.parent.glob(f".{out.name}.*.old"))


def clean_leftovers(out: Path) -> None:
    """Remove what a killed run left beside ``out``; if it died between the two renames, put the old folder back."""
    for path in _leftovers(out):
        if path.suffix == ".old" and not out.exists():
            os.rename(path, out)
        else:
            shutil.rmtree(path, ignore_errors=True)
    if out.is_dir():
        for tmp in out.glob(".*.tmp"):  # write_atomic's temporaries of an older, in-place writer
            tmp.unlink(missing_ok=True)


@contextmanager
def locked(out: Path, flag: str = "--out") -> Iterator[None]:
    """Hold the exclusive lock of ``out`` (:mod:`vlaprobe.locks`) for the duration; clean a killed run's leftovers."""
    with lock_folder(out, flag):
        clean_leftovers(out)
        yield


def replace_folder(out: Path, write: Callable[[Path], None]) -> Path:
    """Have ``write`` fill a fresh folder, then swap it in for ``out`` (whose old files are all dropped)."""
    tag = uuid.uuid4().hex[:8]
    tmp = out.parent / f".{out.name}.{tag}.partial"
    tmp.mkdir(parents=True)
    old = out.parent / f".{out.name}.{tag}.old"
    try:
        write(tmp)
        if out.exists():
            os.rename(out, old)
        try:
            os.rename(tmp, out)
        except BaseException:
            if old.exists():
                os.rename(old, out)
            raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)
    return out


def check_free_space(out: Path, data: ProbeData) -> None:
    """Refuse before training when the folder's disk cannot take the probes (float32 weights of every atom)."""
    atoms = sum(len(v) for v in data.atom_names.values())
    need = 4 * len(data.layers) * (data.hidden_size + 1) * atoms + (16 << 20)  # + evaluation.json and slack
    parent = out
    while not parent.exists():
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    if free < need:
        raise VlaprobeError(
            f"--out {out}: {free / 2**20:.0f} MiB free on its disk, the probes need about {need / 2**20:.0f} MiB; "
            "free some space or choose another --out"
        )
