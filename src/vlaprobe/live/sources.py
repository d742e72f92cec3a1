"""Where an episode's step records come from: the simulator through the one step loop, or a stored episode.

:class:`Simulator` holds the observed model for the server's life and one simulator at a time (rebuilt when
the task changes); each live episode runs through ``vlaprobe.rollout.EpisodeRunner``, as collection's do.
:class:`StoreEpisodes` reads an activation store: its episodes replay without the simulator, as the same
``StepRecord`` (``ActivationStore.episode(key).records()``) paced by ``vlaprobe.rollout.paced``, their stored
images and hidden states going through the same probes and cognition.
"""

from __future__ import annotations

import random
import re
import threading
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from vlaprobe.cognition.plan import stored_task_goal, task_goal
from vlaprobe.collection.defined import TaskColumns, episode_defined
from vlaprobe.configs.collect import DriverName
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.envs.base import TaskEnv
from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.pipeline import STORE_PREFIX, EpisodeSpec
from vlaprobe.policies.base import VLAPolicy
from vlaprobe.rollout import EnvCache, EpisodeControl, EpisodeRunner, StepRecord, make_driver, paced
from vlaprobe.rollout.runner import MakeDriver
from vlaprobe.symbols import HEADS

MakeEnv = Callable[[int], TaskEnv]


class Simulator:
    """The observed model and the current task's simulator, used by one episode at a time."""

    def __init__(
        self,
        policy: VLAPolicy,
        make_env: MakeEnv,
        tasks: dict[int, str],
        *,
        max_steps: int,
        post_success_steps: int = 0,
        seed: int = 0,
        make_driver: MakeDriver = make_driver,
        step_limit: int | None = None,
        num_init_states: int | None = None,
        suite: str = "libero_spatial",
        takeover: TakeoverConfig | None = None,
        atoms: dict[str, list[str]] | None = None,
        no_expert: dict[int, str] | None = None,
    ) -> None:
        """``step_limit``: the longest budget the simulator runs (LIBERO's horizon less the settling steps);
        ``num_init_states``: per task, known up front (a bad init is then refused before the episode starts);
        ``suite``: the LIBERO suite of ``tasks`` (recorded with every episode); ``takeover``: when the
        scripted expert takes over from the policy (``serve --takeover``; None: never); ``atoms``: the
        server's atom names per head, those of the probes (a union suite's: the union of its tasks'
        vocabularies); None: each task's own; ``no_expert``: the tasks whose goal no expert skill handles ->
        that conjunct (an episode the expert would drive or take over is refused)."""
        self.policy, self.tasks, self.suite, self.atoms = policy, tasks, suite, atoms
        self.no_expert = no_expert or {}
        self.takeover = takeover or TakeoverConfig()
        self.runner = EpisodeRunner(policy, EnvCache(make_env, on_new=self._new_env), make_driver)
        self.max_steps, self.post_success_steps = max_steps, post_success_steps
        self.step_limit = step_limit
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self.num_init_states = num_init_states or 0
        self._known_inits = num_init_states

    def _new_env(self, task: int, env: TaskEnv) -> None:
        self.num_init_states = int(env.num_init_states)

    def env_for(self, task: int) -> TaskEnv:
        return self.runner.envs.get(task)

    def resolve_task(self, task: int | str) -> int:
        """A task index from an index or an instruction (trimmed, any case); VlaprobeError if none fits."""
        if isinstance(task, str) and re.fullmatch(r"[0-9]{1,6}", task.strip()):  # ASCII digits: "²" is text
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

    def check_start(self, task: int, init: int | str, max_steps: int | None, driver: str) -> None:
        """Refuse, before the episode is queued, a start the simulator cannot run to its end."""
        if self.takeover.takeover != "none" and driver != "policy":
            raise VlaprobeError(
                f"this server hands the policy's control to the expert (--takeover {self.takeover.takeover}); "
                "start with driver 'policy'"
            )
        if task in self.no_expert and (driver == "expert" or self.takeover.takeover != "none"):
            from vlaprobe.experts.planner import NO_SKILL

            fix = (
                "start it with driver 'policy'"
                if driver == "expert"
                else "choose another task (this server's --takeover hands the policy's control to the expert)"
            )
            raise VlaprobeError(f"task {task}: {NO_SKILL} {self.no_expert[task]}; {fix}")
        if max_steps is not None and max_steps < 1:
            raise VlaprobeError(f"max_steps must be at least 1, got {max_steps}")
        budget = max_steps or self.max_steps
        if self.step_limit is not None and budget > self.step_limit:
            raise VlaprobeError(
                f"max_steps {budget} is more than the simulator runs (LIBERO ends an episode after 1000 steps "
                f"including settling); use at most {self.step_limit}"
            )
        n = self._known_inits
        if n and init != "random" and not 0 <= int(init) < n:
            raise VlaprobeError(f'no init state {init} for task {task}; use 0..{n - 1} or "random"')

    def source(self, task: int, init: int | str, driver: str, max_steps: int | None, seed: int) -> LiveSource:
        """An episode to run (the simulator is built in the episode thread, on the first record)."""
        self.check_start(task, init, max_steps, driver)
        return LiveSource(self, task, init, driver, max_steps or self.max_steps, seed)

    def close(self) -> None:
        self.runner.close()


class LiveSource:
    """One live episode: ``run_episode`` on the simulator with the chosen driver."""

    def __init__(
        self, sim: Simulator, task: int, init: int | str, driver: str, max_steps: int, seed: int
    ) -> None:
        if driver not in ("expert", "policy"):
            raise VlaprobeError(f"unknown driver {driver!r}; use 'expert' or 'policy'")
        self.sim, self.max_steps, self.seed = sim, max_steps, seed
        self.driver: DriverName = "expert" if driver == "expert" else "policy"
        with sim._lock:
            env = sim.env_for(task)
            if init == "random":
                init = sim._rng.randrange(env.num_init_states)
            elif not 0 <= int(init) < env.num_init_states:
                raise VlaprobeError(f"no init state {init} for task {task}; use 0..{env.num_init_states - 1}")
        atoms, self.columns, defined = episode_columns(env, sim.atoms)
        self.env, self.init = env, int(init)
        self.spec = EpisodeSpec(
            task=task,
            instruction=env.instruction,
            init=self.init,
            driver=driver,
            max_steps=max_steps,
            source="live",
            suite=sim.suite,
            goal=task_goal(env.goal_conjunction, env.scene),
            atoms=atoms,
            takeover=sim.takeover.takeover if self.driver == "policy" else "none",
            seed=seed,
            defined=defined,
        )

    def records(self, control: EpisodeControl | None = None) -> Iterator[StepRecord]:
        """The episode's records, their ground truth widened to the server's atoms (0 where undefined)."""
        records = self.sim.runner.run(
            self.env,
            self.driver,
            init=self.init,
            seed=self.seed,
            max_steps=self.max_steps,
            post_success_steps=self.sim.post_success_steps,
            control=control,
            takeover=self.spec.takeover,
            takeover_steps=self.sim.takeover.takeover_steps,
            takeover_until=self.sim.takeover.takeover_until,
        )
        return records if self.columns is None else map(self._widen, records)

    def _widen(self, rec: StepRecord) -> StepRecord:
        assert self.columns is not None
        wide = {
            h: self.columns.widen(h, np.asarray(getattr(rec, f"{h}_atoms"), bool)[None])[0] for h in HEADS
        }
        return replace(rec, object_atoms=wide["object"], action_atoms=wide["action"])


def episode_columns(
    env: TaskEnv, atoms: dict[str, list[str]] | None
) -> tuple[dict[str, list[str]], TaskColumns | None, dict[str, np.ndarray] | None]:
    """A live episode's atoms (``atoms``, else the task's own), where the task's labels sit among them
    (None: in place), and its defined mask (None: every atom), read back from the ``atoms_defined`` attribute
    collection would record for the episode (``collection.defined``): the atoms over objects absent from the
    task, and those the task's labeler cannot label (``should-move-towards`` without a pick-and-place goal)."""
    labeler = env.labeler
    own = {h: list(labeler.vocabulary.atoms(h)) for h in HEADS}
    atoms = own if atoms is None else atoms
    columns = TaskColumns.of(
        atoms,
        own,
        {"action": labeler.undefined_action_atoms},
        advice="serve probes trained on a store that holds this task (--probes)",
    )
    defined = episode_defined(columns.attrs(atoms), atoms) if any(columns.undefined.values()) else None
    in_place = all(np.array_equal(columns.columns[h], np.arange(columns.width[h])) for h in HEADS)
    return atoms, None if in_place else columns, defined


class StoreEpisodes:
    """The episodes of an activation store, listed and replayed through probes and cognition."""

    PREFIX = STORE_PREFIX

    def __init__(self, path: Path) -> None:
        from vlaprobe.collection.store import ActivationStore
        from vlaprobe.collection.verify import require_intact

        self.path = Path(path)
        self.store = ActivationStore.open(path)
        require_intact(path)  # every episode's metadata and chunk files (cheap; decoding waits for a read)
        self.infos = {self.PREFIX + i.key: i for i in self.store.episodes()}
        self._verified: set[str] = set()
        names = self.store.atom_names
        self.atoms = {"object": list(names["object"]), "action": list(names["action"])}
        self.created = self.store.created

    def list(self) -> list[P.EpisodeListItem]:
        out = []
        for eid, info in self.infos.items():
            out.append(
                P.EpisodeListItem(
                    id=eid,
                    source="store",
                    task=info.task,
                    instruction=self.store.episode(info.key).attributes.instruction,
                    init=info.init,
                    driver=str(info.driver),
                    steps=info.length,
                    success=bool(info.success),
                    created=self.created,
                )
            )
        return out

    def verify(self, key: str) -> None:
        """Decode an episode's chunks once before it is first read (``vlaprobe info --verify``'s check): a
        damaged one is refused with the repair, never replayed on fill values."""
        if key in self._verified:
            return
        from vlaprobe.collection.verify import require_intact

        folder = self.path / "episodes" / key
        if not folder.resolve().is_relative_to(self.path.resolve()):
            raise VlaprobeError(f"stored episode {key} lies outside its store; collect it again")
        require_intact(self.path, read=True, keys=[key])
        self._verified.add(key)

    def spec(self, episode_id: str) -> EpisodeSpec:
        info = self.infos.get(episode_id)
        if info is None:
            raise VlaprobeError(f"no stored episode {episode_id!r}; GET /api/episodes lists them")
        self.verify(info.key)
        attrs = self.store.episode(info.key).attributes
        return EpisodeSpec(
            task=info.task,
            instruction=attrs.instruction,
            init=info.init,
            driver=str(info.driver),
            max_steps=info.length,
            source="store",
            suite=self.store.suite,
            goal=stored_task_goal(self.store.suite, info.task, attrs, f"stored episode {info.key}"),
            atoms=self.atoms,
            key=info.key,
            defined=self.store.episode_defined(info.key),
        )

    def source(self, episode_id: str, hz: float | None) -> StoreSource:
        return StoreSource(self, self.spec(episode_id), hz)

    def image(self, episode_id: str, t: int) -> np.ndarray | None:
        info = self.infos.get(episode_id)
        if info is None or not 0 <= t < info.length:
            return None
        self.verify(info.key)
        return np.asarray(self.store.episode(info.key)["image"][t])


class StoreSource:
    """A stored episode's rows, paced at ``hz`` steps per second (None: as fast as they are read)."""

    def __init__(self, episodes: StoreEpisodes, spec: EpisodeSpec, hz: float | None) -> None:
        self.episodes, self.spec, self.hz = episodes, spec, hz

    def records(self, control: EpisodeControl | None = None) -> Iterator[StepRecord]:
        return paced(self.episodes.store.episode(self.spec.key).records(), control, self.hz)
