"""What `vlaprobe cognition` reads, checked: the stores against the probes, extra stores' episodes, and which
episodes' goals the cognition can follow (the others are left out, named, with the reason)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from vlaprobe.cognition.plan import TaskGoal, stored_task_goal, unreadable
from vlaprobe.cognition.readout import HEADS, ProbeReadout
from vlaprobe.configs.env import same_suite
from vlaprobe.errors import VlaprobeError

if TYPE_CHECKING:
    from vlaprobe.collection.store import ActivationStore, EpisodeInfo


@dataclass(frozen=True)
class SkippedEpisode:
    """An episode the cognition left out: its goal names an atom the vocabulary lacks."""

    key: str
    task: int
    reason: str


def episode_goal(store: ActivationStore, key: str, label: str) -> TaskGoal | SkippedEpisode:
    """The goal the cognition follows in a stored episode, or why it cannot follow it."""
    episode = store.episode(key)
    goal = stored_task_goal(
        store.suite, episode.info.task, episode.attributes, f"episode {key} of store {label}"
    )
    atoms = set(store.atom_names["object"]) | set(store.atom_names["action"])
    problem = unreadable(goal, atoms)
    return goal if problem is None else SkippedEpisode(key, episode.info.task, problem)


def load_readout(probes: Path, store: ActivationStore) -> ProbeReadout:
    """The probes' readout; a folder without an action head (``train`` skips a head whose atoms never vary)
    reads the store's action atoms as unknown."""
    from vlaprobe.probes.probeset import ProbeSet

    return ProbeReadout(ProbeSet.load(probes), unknown={"action": store.atom_names.get("action", [])})


def check_store(store: ActivationStore, readout: ProbeReadout, path: Path) -> None:
    """The store fits the probes: its suite, its observer, its atoms."""
    same_suite(f"store {path}", store.suite, f"the probes in {readout.probes.where}", readout.probes.suite)
    if store.model_id != readout.model_id:
        raise VlaprobeError(
            f"store {path} was observed by {store.model_id!r}, not the probes' model; pass its store"
        )
    for h in HEADS:
        if list(readout.atoms[h]) != list(store.atom_names.get(h, [])):
            raise VlaprobeError(
                f"the probes' {h} atoms differ from store {path}'s; pass the store the probes were trained on"
            )


def identity(info: EpisodeInfo) -> tuple[str, int, int, int, int, int]:
    """What tells one recorded episode from another: a copy of a store repeats it under any path."""
    return (info.key, info.task, info.init, info.attempt, info.seed, info.length)


def check_new_episodes(extra: ActivationStore, path: Path, seen: dict[tuple, str], store: Path) -> None:
    """Refuse an extra store that repeats episodes of --store (the probes' own, some trained on) or of another
    extra store: counted twice, or trained-on episodes counted as held out."""
    repeated: dict[str, list[str]] = {}
    for info in extra.episodes():
        where = seen.get(identity(info))
        if where is not None:
            repeated.setdefault(where, []).append(info.key)
        seen[identity(info)] = str(path)
    for where, keys in repeated.items():
        shown = ", ".join(keys[:3]) + (", ..." if len(keys) > 3 else "")
        raise VlaprobeError(
            f"--extra-stores {path} repeats {len(keys)} episode(s) of {where} ({shown}): "
            + (
                "the probes were trained on its episodes, so they would count as held out"
                if where == str(store)
                else "they would be counted twice"
            )
            + "; pass only stores of other episodes (e.g. policy-driven ones)"
        )
