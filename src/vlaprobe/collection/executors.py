"""Where episodes run: in this process, in N spawned processes, or as N Ray actors. Same interface for all.

An executor runs ``Worker.describe`` once and ``Worker.run(unit, seed)`` per unit; the parent submits at most
``capacity`` units at a time and collects finished ones with :meth:`wait`. Only the parent writes the store.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

from vlaprobe.collection.plan import Affinity, Unit
from vlaprobe.collection.worker import EpisodeResult, RunDescription
from vlaprobe.configs.collect import CollectConfig
from vlaprobe.errors import VlaprobeError


class EpisodeRunner(Protocol):
    """What an executor runs: a :class:`~vlaprobe.collection.worker.Worker` or a test's stand-in."""

    def describe(self) -> RunDescription: ...

    def run(self, unit: Unit, seed: int) -> EpisodeResult: ...

    def close(self) -> None: ...


MakeWorker = Callable[[CollectConfig], EpisodeRunner]


class Executor(Protocol):
    """Runs episodes somewhere (this process, worker processes, Ray actors); only the parent writes."""

    capacity: int
    """How many units may be submitted and not yet returned by :meth:`wait`."""

    def describe(self) -> RunDescription:
        """The first worker's description of the model and the suite."""
        ...

    def submit(self, unit: Unit, seed: int) -> None:
        """Start one episode (at most ``capacity`` outstanding)."""
        ...

    def affinity(self) -> Affinity:
        """The simulators held by the worker that takes the next :meth:`submit` and by the others."""
        ...

    def wait(self) -> list[tuple[Unit, EpisodeResult]]:
        """Block until at least one submitted episode finished; return the finished ones."""
        ...

    def close(self) -> None:
        """Stop every worker (also those still running speculative episodes)."""
        ...


class _Simulators:
    """The task of each worker's last unit: the simulator its :class:`~vlaprobe.rollout.EnvCache` holds."""

    def __init__(self) -> None:
        self._task: dict[int, int] = {}

    def ran(self, worker: int, unit: Unit) -> None:
        self._task[worker] = unit.task

    def affinity(self, worker: int | None) -> Affinity:
        """Seen from ``worker`` (None: no worker is idle, nothing to prefer)."""
        if worker is None:
            return Affinity()
        others = frozenset(t for w, t in self._task.items() if w != worker)
        return Affinity(self._task.get(worker), others)


class InlineExecutor:
    """One worker in this process (``--workers 1``)."""

    def __init__(self, cfg: CollectConfig, make_worker: MakeWorker) -> None:
        self.capacity = 1
        self._worker = make_worker(cfg)
        self._queue: deque[tuple[Unit, int]] = deque()
        self._simulators = _Simulators()

    def describe(self) -> RunDescription:
        return self._worker.describe()

    def submit(self, unit: Unit, seed: int) -> None:
        self._queue.append((unit, seed))
        self._simulators.ran(0, unit)

    def affinity(self) -> Affinity:
        return self._simulators.affinity(0)

    def wait(self) -> list[tuple[Unit, EpisodeResult]]:
        unit, seed = self._queue.popleft()
        return [(unit, self._worker.run(unit, seed))]

    def close(self) -> None:
        self._worker.close()


# ----- worker processes -------------------------------------------------------------------------------------------
def _watch_parent(parent: int) -> None:
    """Exit when the parent dies (e.g. kill -9), instead of finishing an episode nobody will write."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _serve(
    index: int, make_worker: MakeWorker, cfg: CollectConfig, inbox: Any, outbox: Any, parent: int
) -> None:
    """Body of a worker process: build the Worker on the first request, then answer requests in order."""
    _watch_parent(parent)
    worker = None
    while True:
        method, args = inbox.get()
        try:
            if worker is None:
                worker = make_worker(cfg)
            outbox.put((index, True, getattr(worker, method)(*args)))
        except Exception as exc:
            error = (
                exc
                if isinstance(exc, VlaprobeError)
                else RuntimeError(f"in worker {index}: {traceback.format_exc()}")
            )
            outbox.put((index, False, error))


class ProcessExecutor:
    """N worker processes (``--workers N``), started with "spawn": LIBERO, MuJoCo and torch are not fork-safe."""

    def __init__(self, cfg: CollectConfig, make_worker: MakeWorker) -> None:
        self.capacity = cfg.workers
        ctx = multiprocessing.get_context("spawn")
        self._outbox = ctx.Queue()
        self._inboxes = [ctx.Queue() for _ in range(cfg.workers)]
        self._procs = [
            ctx.Process(
                target=_serve, args=(i, make_worker, cfg, inbox, self._outbox, os.getpid()), daemon=True
            )
            for i, inbox in enumerate(self._inboxes)
        ]
        for p in self._procs:
            p.start()
        self._idle = list(range(cfg.workers))[::-1]
        self._busy: dict[int, Unit | None] = {}
        self._simulators = _Simulators()

    def _receive(self) -> tuple[int, Any]:
        """The next answer of any busy worker; a one-line error if one died without answering."""
        while True:
            try:
                index, ok, payload = self._outbox.get(timeout=1.0)
            except queue.Empty:
                for i in self._busy:
                    if not self._procs[i].is_alive():
                        code = self._procs[i].exitcode
                        raise VlaprobeError(
                            f"worker process {i} died (exit code {code}) while running {self._busy[i]}; "
                            "see its output above (out of memory? try fewer --workers)"
                        ) from None
                continue
            self._busy.pop(index)
            self._idle.append(index)
            if not ok:
                raise payload
            return index, payload

    def describe(self) -> RunDescription:
        i = self._idle.pop()
        self._busy[i] = None
        self._inboxes[i].put(("describe", ()))
        return self._receive()[1]

    def submit(self, unit: Unit, seed: int) -> None:
        i = self._idle.pop()
        self._busy[i] = unit
        self._simulators.ran(i, unit)
        self._inboxes[i].put(("run", (unit, seed)))

    def affinity(self) -> Affinity:
        return self._simulators.affinity(self._idle[-1] if self._idle else None)

    def wait(self) -> list[tuple[Unit, EpisodeResult]]:
        busy = dict(self._busy)
        index, result = self._receive()
        unit = busy[index]
        assert unit is not None  # describe() is answered by _receive() itself
        return [(unit, result)]

    def close(self) -> None:
        for p in self._procs:  # also ends speculative episodes that are no longer needed
            p.kill()
        for p in self._procs:
            p.join()


# ----- Ray ----------------------------------------------------------------------------------------------------------
class _Actor:
    """A Worker living in a Ray actor (built lazily, like in worker processes)."""

    def __init__(self, make_worker: MakeWorker, cfg: CollectConfig) -> None:
        self._make, self._cfg = make_worker, cfg
        self._worker: EpisodeRunner | None = None

    def call(self, method: str, *args: Any) -> Any:
        if self._worker is None:
            self._worker = self._make(self._cfg)
        return getattr(self._worker, method)(*args)


def _unwrap_ray_error(exc: BaseException) -> BaseException:
    """A worker's VlaprobeError as itself (one line), not as Ray's multi-line RayTaskError."""
    cause = getattr(exc, "cause", None)
    return cause if isinstance(cause, VlaprobeError) else exc


class RayExecutor:
    """N Ray actors (``--ray ADDRESS --workers N``), one work unit per (task, init state) as an actor call."""

    def __init__(self, cfg: CollectConfig, make_worker: MakeWorker) -> None:
        try:
            import ray
        except ImportError:
            raise VlaprobeError("--ray needs Ray: pip install 'vlaprobe[ray]' (or pip install ray)") from None
        self._ray = ray
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            address = None if cfg.ray == "local" else cfg.ray
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False)
            except ConnectionError as exc:
                raise VlaprobeError(
                    f"cannot reach the Ray cluster at {cfg.ray!r} ({exc}); check --ray"
                ) from None
        actor = ray.remote(num_cpus=1, num_gpus=cfg.ray_gpus_per_worker)(_Actor)
        self._actors = [actor.remote(make_worker, cfg) for _ in range(cfg.workers)]
        self.capacity = len(self._actors)
        self._idle = list(range(self.capacity))[::-1]
        self._pending: dict[Any, tuple[Unit, int]] = {}
        self._simulators = _Simulators()

    def _get(self, ref: Any) -> Any:
        try:
            return self._ray.get(ref)
        except Exception as exc:
            raise _unwrap_ray_error(exc) from None

    def describe(self) -> RunDescription:
        return self._get(self._actors[0].call.remote("describe"))  # type: ignore[union-attr]

    def submit(self, unit: Unit, seed: int) -> None:
        i = self._idle.pop()
        self._simulators.ran(i, unit)
        self._pending[self._actors[i].call.remote("run", unit, seed)] = (unit, i)  # type: ignore[union-attr]

    def affinity(self) -> Affinity:
        return self._simulators.affinity(self._idle[-1] if self._idle else None)

    def wait(self) -> list[tuple[Unit, EpisodeResult]]:
        ready, _ = self._ray.wait(list(self._pending), num_returns=1)
        out = []
        for ref in ready:
            unit, i = self._pending.pop(ref)
            self._idle.append(i)
            out.append((unit, self._get(ref)))
        return out

    def close(self) -> None:
        for actor in self._actors:
            self._ray.kill(actor)  # type: ignore[arg-type]
        if self._owns_ray:
            self._ray.shutdown()


def make_executor(cfg: CollectConfig, make_worker: MakeWorker) -> Executor:
    if cfg.ray is not None:
        return RayExecutor(cfg, make_worker)
    if cfg.workers > 1:
        return ProcessExecutor(cfg, make_worker)
    return InlineExecutor(cfg, make_worker)
