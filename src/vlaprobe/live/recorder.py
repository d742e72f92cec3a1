"""Recorded live episodes on disk, readable after the episode ends and after a restart.

Format (one folder per episode under the recordings folder, named by the episode id)::

    <id>/start.json     the episode_start message (written atomically before the first step)
    <id>/steps.jsonl    one step message per line, without its image, appended and flushed every step
    <id>/frames/<t>.jpg the JPEG of step t (the 224x224 upright frame the model saw), t zero-padded to 6
    <id>/end.json       the episode_end message (written atomically; absent: the server stopped mid-episode)

Recordings are private to the server's user (folders 0700, files 0600): they show what the lab did. A line
cut short by a crash, or damaged later, is skipped on reading; every complete line is a whole step. An id
must match :data:`ID_PATTERN` and its folder must lie inside the recordings folder (no ``..``, no symlink
out), so a request can never read a file elsewhere.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from pathlib import Path
from typing import IO

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import write_atomic
from vlaprobe.live import protocol as P

ID_PATTERN = re.compile(r"^[0-9]{8}T[0-9]{6}-[a-z]{1,12}-t[0-9]{2,4}-[0-9a-f]{6}$")
"""A recorded episode's id: ``<UTC time>-<source>-t<task>-<6 hex>`` (what the session names its episodes)."""
FOLDER_MODE, FILE_MODE = 0o700, 0o600


def frame_name(t: int) -> str:
    return f"{t:06d}.jpg"


def inside(root: Path, path: Path) -> bool:
    """``path`` (symlinks resolved) lies inside ``root``."""
    try:
        return path.resolve().is_relative_to(root.resolve())
    except (OSError, RuntimeError):
        return False


def _private(path: Path, mode: int) -> None:
    with contextlib.suppress(OSError):  # a filesystem without modes (e.g. a mounted share)
        os.chmod(path, mode)


class Recorder:
    """Writes one episode (used from the episode thread)."""

    def __init__(self, root: Path, start: P.EpisodeStart) -> None:
        if not ID_PATTERN.match(start.episode_id):
            raise VlaprobeError(f"episode id {start.episode_id!r} is not a recording id")
        root.mkdir(parents=True, exist_ok=True, mode=FOLDER_MODE)
        self.folder = root / start.episode_id
        for folder in (self.folder, self.folder / "frames"):
            folder.mkdir(exist_ok=True, mode=FOLDER_MODE)
            _private(folder, FOLDER_MODE)
        self._write(self.folder / "start.json", start.model_dump_json() + "\n")
        fd = os.open(self.folder / "steps.jsonl", os.O_WRONLY | os.O_APPEND | os.O_CREAT, FILE_MODE)
        self._steps: IO[str] = open(fd, "a", encoding="utf-8")  # noqa: SIM115

    @staticmethod
    def _write(path: Path, data: str | bytes) -> None:
        write_atomic(path, data, mode=FILE_MODE)

    def step(self, t: int, state: str, jpeg: bytes | None) -> None:
        if jpeg is not None:
            self._write(self.folder / "frames" / frame_name(t), jpeg)
        self._steps.write(state + "\n")
        self._steps.flush()

    def end(self, end: P.EpisodeEnd) -> None:
        self._steps.close()
        self._write(self.folder / "end.json", end.model_dump_json() + "\n")

    def close(self) -> None:
        if not self._steps.closed:
            self._steps.close()


class Damaged(VlaprobeError):
    """A recording whose start cannot be read (answered 422 with one line)."""


class Recordings:
    """Reads the recordings folder; what is damaged is skipped (lines, end.json) or named (start.json)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def _folder(self, episode_id: str) -> Path | None:
        """The episode's folder: a valid id, inside the recordings folder, with a start file."""
        if not ID_PATTERN.match(episode_id):
            return None
        folder = self.root / episode_id
        if not (inside(self.root, folder) and (folder / "start.json").is_file()):
            return None
        return folder

    def list(self) -> list[P.EpisodeListItem]:
        if not self.root.is_dir():
            return []
        items = []
        for folder in sorted(self.root.iterdir()):
            if self._folder(folder.name) is None:
                continue  # not a recording
            try:
                start = _start(folder)
            except Damaged:
                continue  # its start is unreadable: nothing to list it by (GET names the damage)
            end = _end(folder)
            items.append(
                P.EpisodeListItem(
                    id=start.episode_id,
                    source="live",
                    task=start.task,
                    instruction=start.instruction,
                    init=start.init,
                    driver=start.driver,
                    steps=end.steps if end is not None else len(_steps(folder)),
                    success=None if end is None else end.success,
                    stopped=end is not None and end.stopped,
                    created=_created(start.episode_id),
                )
            )
        return items

    def get(self, episode_id: str) -> P.EpisodeRecord | None:
        """The episode's start, every readable step and its end (None if cut short or damaged)."""
        folder = self._folder(episode_id)
        if folder is None:
            return None
        return P.EpisodeRecord(start=_start(folder), steps=_steps(folder), end=_end(folder))

    def frame(self, episode_id: str, t: int) -> bytes | None:
        folder = self._folder(episode_id)
        if folder is None or not 0 <= t < 10**6:
            return None
        path = folder / "frames" / frame_name(t)
        if not (path.is_file() and inside(self.root, path)):
            return None
        try:
            return path.read_bytes()
        except OSError:
            return None


def _start(folder: Path) -> P.EpisodeStart:
    try:
        return P.EpisodeStart.model_validate_json((folder / "start.json").read_bytes())
    except (OSError, ValueError) as exc:
        kind = "unreadable" if isinstance(exc, OSError) else "damaged"
        raise Damaged(
            f"recording {folder.name} cannot be read: its start.json is {kind}; delete the folder {folder.name} "
            "from the recordings folder"
        ) from None


def _end(folder: Path) -> P.EpisodeEnd | None:
    """The end message; None when absent (the server stopped mid-episode) or damaged."""
    try:
        return P.EpisodeEnd.model_validate_json((folder / "end.json").read_bytes())
    except (OSError, ValueError):
        return None


def _steps(folder: Path) -> list[P.Step]:
    """Every complete, readable step line (a line cut short or damaged is skipped, as after a crash)."""
    try:
        text = (folder / "steps.jsonl").read_bytes().decode("utf-8", "replace")
    except OSError:
        return []
    steps = []
    for line in text.split("\n")[:-1]:  # the last piece has no newline: cut short or empty
        try:
            data = json.loads(line)
            if isinstance(data, dict):
                data.setdefault("image", None)
            steps.append(P.Step.model_validate(data))
        except ValueError:  # pydantic's ValidationError is one
            continue
    return steps


def _created(episode_id: str) -> str:
    """Episode ids begin with their UTC start time, YYYYmmddTHHMMSS."""
    s = episode_id[:15]
    if len(s) == 15 and s[8] == "T" and s.replace("T", "").isdigit():
        return f"{s[0:4]}-{s[4:6]}-{s[6:8]}T{s[9:11]}:{s[11:13]}:{s[13:15]}Z"
    return ""
