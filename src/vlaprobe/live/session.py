"""The episode thread: one episode at a time, its records turned into messages, recorded and handed to the hub.

The simulator, the model and the probes run here, off the event loop, so the server keeps answering while a
step takes hundreds of milliseconds. It is ONE thread for the server's life, not one per episode: the
offscreen renderer's GL context belongs to the thread that created the simulator, and a simulator stepped
from another thread renders black frames (measured with OSMesa: mean pixel 0.02 instead of 119). Commands
from clients reach the episode through its control object (stop, pause, resume, drop), which the step loop
checks between steps.
"""

from __future__ import annotations

import base64
import queue
import sys
import threading
import traceback
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.hub import Hub
from vlaprobe.live.pipeline import EpisodeSpec, StepBuilder
from vlaprobe.live.recorder import Recorder


class Control(Protocol):
    """Between-step commands (the step loop's ``EpisodeControl``)."""

    def stop(self) -> None: ...
    def pause(self) -> None: ...
    def resume(self) -> None: ...
    def drop(self, steps: int = 8) -> None: ...

    @property
    def stopped(self) -> bool: ...


class EpisodeSource(Protocol):
    """One episode's step records: a live simulator run or a stored episode."""

    spec: EpisodeSpec

    def records(self, control: Any) -> Iterator[Any]: ...


def encode_jpeg(image: np.ndarray, quality: int = 90) -> bytes:
    """JPEG of an (H, W, 3) uint8 frame (the paper sent quality 90)."""
    import simplejpeg

    return simplejpeg.encode_jpeg(
        np.ascontiguousarray(image, dtype=np.uint8), quality=quality, colorspace="RGB"
    )


def new_episode_id(task: int, source: str) -> str:
    now = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S")
    return f"{now}-{source}-t{task:02d}-{uuid.uuid4().hex[:6]}"


@dataclass
class Run:
    episode_id: str
    source: str
    """"live" (the simulator) or "replay" (a stored episode)."""
    control: Any
    done: threading.Event = field(default_factory=threading.Event)


class Session:
    """Starts episodes (one at a time) and runs them in the episode thread."""

    def __init__(
        self,
        hub: Hub,
        make_builder: Callable[[EpisodeSpec, str], StepBuilder],
        recordings: Path | None,
        on_exit: Callable[[], None] | None = None,
    ) -> None:
        """``on_exit`` runs in the episode thread when the session closes (closing the simulator there)."""
        self.hub, self.make_builder, self.recordings = hub, make_builder, recordings
        self.running: Run | None = None
        self._lock = threading.Lock()
        self._jobs: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._on_exit = on_exit
        self._thread = threading.Thread(target=self._work, name="episodes", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            self._run(*job)
        if self._on_exit is not None:
            self._on_exit()

    def start(
        self, task: int, source: str, make_source: Callable[[], EpisodeSource], control: Any, record: bool
    ) -> str:
        """Start an episode; VlaprobeError if one is running. ``make_source`` runs in the episode thread."""
        with self._lock:
            if self.running is not None:
                raise VlaprobeError(
                    f"episode {self.running.episode_id} is running; send stop or wait for its episode_end"
                )
            if not self._thread.is_alive():
                raise VlaprobeError("the server is shutting down; start the episode on the next one")
            run = Run(new_episode_id(task, source), source, control)
            self.running = run
            self._jobs.put((run, make_source, record))
        return run.episode_id

    def _finished(self, run: Run) -> None:
        with self._lock:
            if self.running is run:
                self.running = None

    def _run(self, run: Run, make_source: Callable[[], EpisodeSource], record: bool) -> None:
        hub, recorder, builder, began = self.hub, None, None, False
        try:
            source = make_source()
            builder = self.make_builder(source.spec, run.episode_id)
            start = builder.start_message()
            if record and self.recordings is not None:
                recorder = Recorder(self.recordings, start)
            hub.threadsafe(hub.begin, run.episode_id, start.model_dump_json())
            began = True
            for rec in source.records(run.control):
                msg = builder.step(rec, getattr(rec, "timings", None))
                msg.drop_left = int(getattr(run.control, "drop_left", 0))
                jpeg = encode_jpeg(rec.model_image)
                state = msg.model_dump_json(exclude={"image"})
                if recorder is not None:
                    recorder.step(msg.t, state, jpeg)
                hub.threadsafe(hub.step, state, base64.b64encode(jpeg).decode("ascii"))
        except Exception as exc:
            message = (
                str(exc) if isinstance(exc, VlaprobeError) else f"episode failed: {type(exc).__name__}: {exc}"
            )
            if not isinstance(exc, VlaprobeError):
                traceback.print_exc(file=sys.stderr)
            hub.threadsafe(hub.broadcast, P.ErrorMessage(message=message.splitlines()[0]).model_dump_json())
            run.control.stop()
        finally:
            try:
                if builder is not None and began:
                    end = builder.end_message(stopped=bool(run.control.stopped))
                    if recorder is not None:
                        recorder.end(end)
                    hub.threadsafe(hub.end, end.model_dump_json())
            finally:
                if recorder is not None:
                    recorder.close()
                hub.threadsafe(self._finished, run)
                run.done.set()

    def close(self, timeout: float = 10.0) -> None:
        """Stop the running episode and end the episode thread (server shutdown)."""
        run = self.running
        if run is not None:
            run.control.stop()
            run.control.resume()
        self._jobs.put(None)
        self._thread.join(timeout)
