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
import contextlib
import queue
import re
import sys
import threading
import traceback
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Protocol

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.hub import Hub
from vlaprobe.live.pipeline import EpisodeSpec, StepBuilder
from vlaprobe.live.recorder import Recorder
from vlaprobe.rollout import EpisodeControl, StepRecord


class EpisodeSource(Protocol):
    """One episode's step records: a live simulator run or a stored episode."""

    spec: EpisodeSpec

    def records(self, control: EpisodeControl | None = None) -> Iterator[StepRecord]: ...


def encode_jpeg(image: np.ndarray, quality: int = 90) -> bytes:
    """JPEG of an (H, W, 3) uint8 frame (the paper sent quality 90)."""
    import simplejpeg

    return simplejpeg.encode_jpeg(
        np.ascontiguousarray(image, dtype=np.uint8), quality=quality, colorspace="RGB"
    )


_ABSOLUTE_PATH = re.compile(r"(?<![\w.:/~-])/(?:[^\s/'\"]+/)+")


def public_message(exc: BaseException | str) -> str:
    """One line for clients: the error's message without the server's absolute paths (only the last part of a
    path is kept) and without a traceback."""
    if isinstance(exc, OSError) and exc.strerror:
        name = Path(str(exc.filename)).name if exc.filename else ""
        text = f"episode failed: {exc.strerror}" + (
            f" ({name}); check --recordings and the disk" if name else ""
        )
    elif isinstance(exc, BaseException):
        text = str(exc) if isinstance(exc, VlaprobeError) else f"episode failed: {type(exc).__name__}: {exc}"
    else:
        text = exc
    lines = text.strip().splitlines() or ["error"]
    return _ABSOLUTE_PATH.sub("", lines[0])[:500]


def new_episode_id(task: int, source: str) -> str:
    now = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S")
    return f"{now}-{source}-t{task:02d}-{uuid.uuid4().hex[:6]}"


@dataclass
class Run:
    episode_id: str
    source: str
    """"live" (the simulator) or "replay" (a stored episode)."""
    control: EpisodeControl
    on_error: Callable[[str], None] | None = None
    """Tells the client that asked for the episode why it could not begin (other clients never saw it)."""
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
        self._jobs: queue.SimpleQueue[tuple[Run, Callable[[], EpisodeSource], bool] | None] = (
            queue.SimpleQueue()
        )
        self._on_exit = on_exit
        self._thread = threading.Thread(target=self._work, name="episodes", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            self._run(*job)
        if self._on_exit is not None:
            self._on_exit()

    def start(
        self,
        task: int,
        source: str,
        make_source: Callable[[], EpisodeSource],
        control: EpisodeControl,
        record: bool,
        on_error: Callable[[str], None] | None = None,
    ) -> str:
        """Start an episode; VlaprobeError if one is running. ``make_source`` runs in the episode thread; if it
        or the episode's start fails, ``on_error`` (on the event loop) gets the one-line reason, else every
        client does."""
        with self._lock:
            if self.running is not None:
                raise VlaprobeError(
                    f"episode {self.running.episode_id} is running; send stop or wait for its episode_end"
                )
            if not self._thread.is_alive():
                raise VlaprobeError("the server is shutting down; start the episode on the next one")
            run = Run(new_episode_id(task, source), source, control, on_error)
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
                msg = builder.step(rec)
                msg.drop_left = run.control.drop_left
                if (reason := builder.take_request()) is not None:
                    run.control.take_over(reason)  # the expert acts from the next step on
                if (back := builder.take_hand_back()) is not None:
                    run.control.hand_back(back)  # the policy acts from the next step on
                jpeg = encode_jpeg(rec.model_image)
                state = msg.model_dump_json(exclude={"image"})
                if recorder is not None:
                    recorder.step(msg.t, state, jpeg)
                hub.threadsafe(hub.step, state, base64.b64encode(jpeg).decode("ascii"))
        except Exception as exc:
            message = public_message(exc)
            if not isinstance(exc, VlaprobeError):
                traceback.print_exc(file=sys.stderr)
            if not began and run.on_error is not None:
                hub.threadsafe(run.on_error, message)  # a start that could not begin: its sender's error
            else:
                hub.threadsafe(hub.broadcast, P.ErrorMessage(message=message).model_dump_json())
            run.control.stop()
        finally:
            self._close(run, builder if began else None, recorder)

    def _close(self, run: Run, builder: StepBuilder | None, recorder: Recorder | None) -> None:
        """Write the end, then announce it and free the session in ONE loop callback: a start sent the moment
        a client reads ``episode_end`` is accepted, and a stop sent with it reaches the new episode."""
        end_text = None
        try:
            if builder is not None:
                end = builder.end_message(stopped=bool(run.control.stopped))
                end_text = end.model_dump_json()
                if recorder is not None:
                    recorder.end(end)
        except Exception:  # the recording's end could not be written: the episode still ends for clients
            traceback.print_exc(file=sys.stderr)
        finally:
            if recorder is not None:
                with contextlib.suppress(OSError):
                    recorder.close()

            def over() -> None:
                if end_text is not None:
                    self.hub.end(end_text)
                self._finished(run)

            self.hub.threadsafe(over)
            run.done.set()

    def close(self, timeout: float = 10.0) -> None:
        """Stop the running episode and end the episode thread (server shutdown)."""
        run = self.running
        if run is not None:
            run.control.stop()
            run.control.resume()
        self._jobs.put(None)
        self._thread.join(timeout)
