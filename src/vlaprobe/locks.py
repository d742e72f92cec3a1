"""One writer per output folder: an exclusive OS lock that a second writer is refused and a killed one releases.

The lock is an ``flock`` on ``.<name>.lock`` beside the folder (beside, so that a command that replaces its
folder whole keeps holding it). The file holds the holder's pid and command line, which a refused writer is
told. The kernel releases an ``flock`` when its holder dies, even by ``kill -9``: a stale lock file is simply
taken over by the next writer. The file is removed when the lock is released, and a writer that locked a file
another one removed in the meantime tries again, so two writers never hold locks on two different files.
"""

from __future__ import annotations

import fcntl
import os
import shlex
import sys
from pathlib import Path
from types import TracebackType

from vlaprobe.errors import VlaprobeError


def lock_path(out: Path) -> Path:
    """The lock file of the folder ``out``."""
    return out.parent / f".{out.name}.lock"


def holder(out: Path) -> str:
    """Who holds (or last held) the lock of ``out``: "pid N (command)", or "another process"."""
    try:
        pid, _, command = lock_path(out).read_text(encoding="utf-8").partition("\n")
    except (OSError, UnicodeDecodeError):
        return "another process"
    pid = pid.strip()
    if not pid.isdigit():
        return "another process"
    command = command.strip()
    return f"pid {pid}" + (f" ({command})" if command else "")


class FolderLock:
    """An exclusive lock on one output folder; release it with :meth:`release` or by leaving a ``with``."""

    def __init__(self, out: Path, fd: int, made: list[Path]) -> None:
        self.out = out
        self._fd = fd
        self._made = made

    @property
    def held(self) -> bool:
        return self._fd >= 0

    def release(self) -> None:
        """Remove the lock file, then drop the lock (in that order: see the module docstring); remove the
        parent folders the lock created if they are still empty (a refused command leaves nothing behind)."""
        if self._fd < 0:
            return
        try:
            lock_path(self.out).unlink(missing_ok=True)
        finally:
            os.close(self._fd)
            self._fd = -1
        for folder in self._made:
            try:
                folder.rmdir()
            except OSError:
                break  # not empty (or gone): neither are its parents

    def __enter__(self) -> FolderLock:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.release()


def lock_folder(out: str | Path, flag: str = "--out", command: str | None = None) -> FolderLock:
    """Lock ``out`` (which may not exist yet) for this process, or refuse in one line naming the holder.

    ``command`` is recorded for a refused writer to read (default: this process's command line).
    """
    out = Path(out)
    made = [p for p in out.parents if not p.exists()]  # deepest first
    out.parent.mkdir(parents=True, exist_ok=True)
    path = lock_path(out)
    text = f"{os.getpid()}\n{command if command is not None else shlex.join(sys.argv)}\n".encode()
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise VlaprobeError(
                f"{flag} {out} is being written by {holder(out)}; wait for it to finish or use another {flag}"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if not same:  # the previous holder removed this file after we opened it: lock the new one
            os.close(fd)
            continue
        os.ftruncate(fd, 0)
        os.pwrite(fd, text, 0)
        return FolderLock(out, fd, made)
