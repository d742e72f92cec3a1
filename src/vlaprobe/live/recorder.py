"""Recorded live episodes on disk, readable after the episode ends and after a restart.

Format (one folder per episode under the recordings folder, named by the episode id)::

    <id>/start.json     the episode_start message (written atomically before the first step)
    <id>/steps.jsonl    one step message per line, without its image, appended and flushed every step
    <id>/frames/<t>.jpg the JPEG of step t (the 224x224 upright frame the model saw), t zero-padded to 6
    <id>/end.json       the episode_end message (written atomically; absent: the server stopped mid-episode)

A line cut short by a crash is ignored on reading; every complete line is a whole step.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import IO

from vlaprobe.files import write_atomic
from vlaprobe.live import protocol as P

ID_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,80}$")


def frame_name(t: int) -> str:
    return f"{t:06d}.jpg"


class Recorder:
    """Writes one episode (used from the episode thread)."""

    def __init__(self, root: Path, start: P.EpisodeStart) -> None:
        self.folder = root / start.episode_id
        (self.folder / "frames").mkdir(parents=True, exist_ok=True)
        write_atomic(self.folder / "start.json", start.model_dump_json() + "\n")
        self._steps: IO[str] = open(self.folder / "steps.jsonl", "a", encoding="utf-8")  # noqa: SIM115

    def step(self, t: int, state: str, jpeg: bytes | None) -> None:
        if jpeg is not None:
            write_atomic(self.folder / "frames" / frame_name(t), jpeg)
        self._steps.write(state + "\n")
        self._steps.flush()

    def end(self, end: P.EpisodeEnd) -> None:
        self._steps.close()
        write_atomic(self.folder / "end.json", end.model_dump_json() + "\n")

    def close(self) -> None:
        if not self._steps.closed:
            self._steps.close()


class Recordings:
    """Reads the recordings folder."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def _folder(self, episode_id: str) -> Path | None:
        if not ID_PATTERN.match(episode_id):
            return None
        folder = self.root / episode_id
        return folder if (folder / "start.json").is_file() else None

    def list(self) -> list[P.EpisodeListItem]:
        if not self.root.is_dir():
            return []
        items = []
        for folder in sorted(self.root.iterdir()):
            try:
                start = P.EpisodeStart.model_validate_json((folder / "start.json").read_text())
                end_path = folder / "end.json"
                end = P.EpisodeEnd.model_validate_json(end_path.read_text()) if end_path.is_file() else None
            except (OSError, ValueError):
                continue  # not a recording, or damaged: skipped rather than failing the list
            steps = end.steps if end is not None else len(self._lines(folder))
            items.append(
                P.EpisodeListItem(
                    id=start.episode_id,
                    source="live",
                    task=start.task,
                    instruction=start.instruction,
                    init=start.init,
                    driver=start.driver,
                    steps=steps,
                    success=None if end is None else end.success,
                    stopped=end is not None and end.stopped,
                    created=_created(start.episode_id),
                )
            )
        return items

    @staticmethod
    def _lines(folder: Path) -> list[str]:
        path = folder / "steps.jsonl"
        if not path.is_file():
            return []
        lines = path.read_text(encoding="utf-8").split("\n")
        return [ln for ln in lines[:-1] if ln]  # the last piece has no newline: cut short or empty

    def get(self, episode_id: str) -> P.EpisodeRecord | None:
        folder = self._folder(episode_id)
        if folder is None:
            return None
        start = P.EpisodeStart.model_validate_json((folder / "start.json").read_text())
        steps = []
        for line in self._lines(folder):
            data = json.loads(line)
            data.setdefault("image", None)
            steps.append(P.Step.model_validate(data))
        end_path = folder / "end.json"
        end = P.EpisodeEnd.model_validate_json(end_path.read_text()) if end_path.is_file() else None
        return P.EpisodeRecord(start=start, steps=steps, end=end)

    def frame(self, episode_id: str, t: int) -> bytes | None:
        folder = self._folder(episode_id)
        if folder is None or t < 0:
            return None
        path = folder / "frames" / frame_name(t)
        return path.read_bytes() if path.is_file() else None


def _created(episode_id: str) -> str:
    """Episode ids begin with their UTC start time, YYYYmmddTHHMMSS."""
    s = episode_id[:15]
    if len(s) == 15 and s[8] == "T" and s.replace("T", "").isdigit():
        return f"{s[0:4]}-{s[4:6]}-{s[6:8]}T{s[9:11]}:{s[11:13]}:{s[13:15]}Z"
    return ""
