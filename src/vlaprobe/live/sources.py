"""Where an episode's step records come from: the simulator through the one step loop, or a stored episode.

:class:`Simulator` holds the observed model for the server's life and one simulator at a time (rebuilt when
the task changes); each live episode runs ``vlaprobe.rollout.run_episode``, the loop collection runs.
:class:`StoreEpisodes` reads an activation store: its episodes replay without the simulator, their stored
images and hidden states going through the same probes and cognition.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.pipeline import STORE_PREFIX, EpisodeSpec
from vlaprobe.rollout import EpisodeControl, make_driver, run_episode

MakeEnv = Callable[[int], Any]
MakeDriver = Callable[[str, Any, Any, int], Any]


class Simulator:
    """The observed model and the current task's simulator, used by one episode at a time."""

    def __init__(
        self,
        policy: Any,
        make_env: MakeEnv,
        tasks: dict[int, str],
        *,
        max_steps: int,
        post_success_steps: int = 0,
        seed: int = 0,
        make_driver: MakeDriver = make_driver,
    ) -> None:
        self.policy, self.tasks = policy, tasks
        self._make_env, self._make_driver = make_env, make_driver
        self.max_steps, self.post_success_steps = max_steps, post_success_steps
        self._rng = random.Random(seed)
        self._env: Any = None
        self._lock = threading.Lock()
        self.num_init_states = 0

    def env_for(self, task: int) -> Any:
        if self._env is None or self._env.task_index != task:
            if self._env is not None:
                self._env.close()
                self._env = None
            self._env = self._make_env(task)
            self.num_init_states = int(self._env.num_init_states)
        return self._env

    def resolve_task(self, task: int | str) -> int:
        """A task index from an index or an instruction (trimmed, any case); VlaprobeError if none fits."""
        if isinstance(task, str) and task.strip().isdigit():
            task = int(task.strip())
        if isinstance(task, int):
            if task not in self.tasks:
                raise VlaprobeError(f"no task {task}; tasks are 0..{max(self.tasks)} (see hello.tasks)")
            return task
        wanted = " ".join(task.split()).lower()
        for index, instruction in self.tasks.items():
            if " ".join(instruction.split()).lower() == wanted:
                return index
        raise VlaprobeError(f"unknown task instruction {task[:80]!r}; send one of hello.tasks or an index")

    def source(self, task: int, init: int | str, driver: str, max_steps: int | None, seed: int) -> LiveSource:
        """An episode to run (the simulator is built in the episode thread, on the first record)."""
        if max_steps is not None and max_steps < 1:
            raise VlaprobeError(f"max_steps must be at least 1, got {max_steps}")
        return LiveSource(self, task, init, driver, max_steps or self.max_steps, seed)

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
            self._env = None


class LiveSource:
    """One live episode: ``run_episode`` on the simulator with the chosen driver."""

    def __init__(
        self, sim: Simulator, task: int, init: int | str, driver: str, max_steps: int, seed: int
    ) -> None:
        self.sim, self.driver, self.max_steps, self.seed = sim, driver, max_steps, seed
        with sim._lock:
            env = sim.env_for(task)
            if init == "random":
                init = sim._rng.randrange(env.num_init_states)
            elif not 0 <= int(init) < env.num_init_states:
                raise VlaprobeError(f"no init state {init} for task {task}; use 0..{env.num_init_states - 1}")
        vocab = env.labeler.vocabulary
        self.env, self.init = env, int(init)
        self.spec = EpisodeSpec(
            task=task,
            instruction=env.instruction,
            init=self.init,
            driver=driver,
            max_steps=max_steps,
            source="live",
            goal=env.goal,
            atoms={"object": list(vocab.object_atoms), "action": list(vocab.action_atoms)},
        )

    def records(self, control: EpisodeControl) -> Iterator[Any]:
        driver = self.sim._make_driver(self.driver, self.env, self.sim.policy, self.seed)
        yield from run_episode(
            self.env,
            self.sim.policy,
            driver,
            init=self.init,
            max_steps=self.max_steps,
            post_success_steps=self.sim.post_success_steps,
            control=control,
        )


@dataclass
class StoredStep:
    """One stored row, shaped like the step loop's record for the message builder."""

    t: int
    model_image: np.ndarray
    hidden: np.ndarray
    object_atoms: np.ndarray
    action_atoms: np.ndarray
    action: np.ndarray
    predicted_action: np.ndarray
    success: bool
    terminal: bool
    timings: Any = None


class StoreEpisodes:
    """The episodes of an activation store, listed and replayed through probes and cognition."""

    PREFIX = STORE_PREFIX

    def __init__(self, path: Path) -> None:
        from vlaprobe.collection.store import ActivationStore

        self.store = ActivationStore.open(path)
        self.infos = {self.PREFIX + i.key: i for i in self.store.episodes()}
        names = self.store.meta["atom_names"]
        self.atoms = {"object": list(names["object"]), "action": list(names["action"])}
        self.created = str(self.store.meta.get("created", ""))

    def list(self) -> list[P.EpisodeListItem]:
        out = []
        for eid, info in self.infos.items():
            out.append(
                P.EpisodeListItem(
                    id=eid,
                    source="store",
                    task=info.task,
                    instruction=str(self._attrs(info.key).get("instruction", "")),
                    init=info.init,
                    driver=str(info.driver),
                    steps=info.length,
                    success=bool(info.success),
                    created=self.created,
                )
            )
        return out

    def _attrs(self, key: str) -> dict[str, Any]:
        return dict(self.store.episode(key).attrs)

    def spec(self, episode_id: str) -> EpisodeSpec:
        from vlaprobe.symbols import Goal

        info = self.infos.get(episode_id)
        if info is None:
            raise VlaprobeError(f"no stored episode {episode_id!r}; GET /api/episodes lists them")
        attrs = self._attrs(info.key)
        return EpisodeSpec(
            task=info.task,
            instruction=str(attrs.get("instruction", "")),
            init=info.init,
            driver=str(info.driver),
            max_steps=info.length,
            source="store",
            goal=Goal(**attrs["goal"]),
            atoms=self.atoms,
            key=info.key,
        )

    def source(self, episode_id: str, hz: float | None) -> StoreSource:
        return StoreSource(self, self.spec(episode_id), hz)

    def image(self, episode_id: str, t: int) -> np.ndarray | None:
        info = self.infos.get(episode_id)
        if info is None or not 0 <= t < info.length:
            return None
        return np.asarray(self.store.episode(info.key)["image"][t])


class StoreSource:
    """A stored episode's rows, paced at ``hz`` steps per second (None: as fast as they are read)."""

    def __init__(self, episodes: StoreEpisodes, spec: EpisodeSpec, hz: float | None) -> None:
        self.episodes, self.spec, self.hz = episodes, spec, hz

    def records(self, control: EpisodeControl | None = None) -> Iterator[StoredStep]:
        info = self.episodes.infos[StoreEpisodes.PREFIX + self.spec.key]
        arrays = self.episodes.store.episode(self.spec.key)
        hidden = np.asarray(arrays["hidden"])  # (layers, T, ...) as stored
        cols = {
            k: np.asarray(arrays[k])
            for k in ("image", "object_atoms", "action_atoms", "action", "predicted_action")
        }
        n = info.length
        next_at = time.monotonic()
        for t in range(n):
            if control is not None:
                control.wait_while_paused()
                if control.stopped:
                    return
            if self.hz:
                time.sleep(max(0.0, next_at - time.monotonic()))
                next_at = max(next_at + 1.0 / self.hz, time.monotonic() - 1.0)
            last = t == n - 1
            yield StoredStep(
                t=t,
                model_image=cols["image"][t],
                hidden=hidden[:, t].astype(np.float32),
                object_atoms=cols["object_atoms"][t],
                action_atoms=cols["action_atoms"][t],
                action=cols["action"][t],
                predicted_action=cols["predicted_action"][t],
                success=info.success_step is not None and t >= info.success_step,
                terminal=last,
            )
