"""Small shared file helpers: atomic writes, and the package versions recorded with every output."""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

# Packages whose versions shape recorded data, probes and reports.
VERSIONED = ("torch", "numpy", "zarr", "mujoco", "robosuite", "libero", "transformers", "ray")


def _file_mode() -> int:
    """Permissions of a newly created file under the current umask (mkstemp would leave 0600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def write_atomic(path: str | Path, data: bytes | str | Callable[[str], object]) -> None:
    """Write ``path`` under a temporary name in the same folder, then rename it into place.

    ``data`` is the content, or a function that writes the file whose path it is given (e.g. safetensors'
    ``save_file``). A reader never sees a half-written file; a failure leaves no temporary behind.
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
        os.chmod(tmp, _file_mode())
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
