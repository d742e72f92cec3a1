"""The vocabulary of a whole suite: the union of its tasks' scenes, and which atoms each task defines.

The tasks of LIBERO-object, -10 and -90 have different objects. Probing across them needs one atom order, so the
suite's vocabulary is that of the **union scene** (every object, fixture and region of any task, in first-seen
order, task by task). An atom over a name absent from a task is **undefined** in that task (its mask entry is
False): never scored as false, since nothing in the task can make it true or false.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vlaprobe.configs.env import SuiteName
from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols import Articulation, Scene, Vocabulary, build_vocabulary, parse_atom


@dataclass(frozen=True)
class SuiteVocabulary:
    """The union vocabulary of a suite and, per task, which of its atoms are defined."""

    suite: str
    vocabulary: Vocabulary
    scenes: tuple[Scene, ...]
    """Each task's own scene, in task order."""
    object_defined: np.ndarray
    """(tasks, object atoms) bool: the atom's arguments all exist in the task."""
    action_defined: np.ndarray
    """(tasks, action atoms) bool, same."""

    def defined(self, head: str) -> np.ndarray:
        """The (tasks, atoms) mask of one head."""
        if head == "object":
            return self.object_defined
        if head == "action":
            return self.action_defined
        raise ValueError(f"unknown head {head!r}")


def _ordered_union(groups: Sequence[tuple[str, ...]]) -> tuple[str, ...]:
    return tuple(dict.fromkeys(name for group in groups for name in group))


def _rules(scenes: Sequence[Scene], names: str, rules: str) -> dict[str, Articulation]:
    """Name -> rule over every scene (``names``/``rules``: parallel Scene fields); a name whose rule differs
    between tasks cannot share one atom."""
    out: dict[str, Articulation] = {}
    for scene in scenes:
        for name, rule in zip(getattr(scene, names), getattr(scene, rules), strict=True):
            if out.setdefault(name, rule) != rule:
                raise VlaprobeError(f"{name} has different joint rules in two tasks ({out[name]} vs {rule})")
    return out


def union_scene(scenes: Sequence[Scene]) -> Scene:
    """Every object, fixture and region of ``scenes``, first-seen order (``union_scene([s]) == s``)."""

    def union(field: str) -> tuple[str, ...]:
        return _ordered_union([getattr(s, field) for s in scenes])

    containers, doors, on_off = union("containers"), union("doors"), union("on_off")
    opens = _rules(scenes, "containers", "container_articulation") | _rules(
        scenes, "doors", "door_articulation"
    )
    closes = {
        n: r
        for s in scenes
        if s.close_articulation
        for n, r in zip(s.openable, s.close_articulation, strict=True)
    }
    offs = {
        n: r for s in scenes if s.off_articulation for n, r in zip(s.on_off, s.off_articulation, strict=True)
    }
    turns = _rules(scenes, "on_off", "on_off_articulation")
    parents: dict[str, str] = {}
    for s in scenes:
        parents.update(s.region_parent)
    return Scene(
        pickupable=union("pickupable"),
        fixtures=union("fixtures"),
        containers=containers,
        container_articulation=tuple(opens[c] for c in containers),
        surfaces=union("surfaces"),
        on_off=on_off,
        on_off_articulation=tuple(turns[k] for k in on_off),
        region_parent=parents,
        receptacles=union("receptacles"),
        doors=doors,
        door_articulation=tuple(opens[d] for d in doors),
        close_articulation=tuple(closes[n] for n in containers + doors) if len(closes) == len(opens) else (),
        off_articulation=tuple(offs[k] for k in on_off) if len(offs) == len(turns) else (),
    )


def defined_mask(atoms: Sequence[str], scene: Scene) -> np.ndarray:
    """(atoms,) bool: every argument of the atom is an object or region of ``scene``."""
    names = set(scene.tabletop) | set(scene.regions)
    return np.array([set(parse_atom(a)[1]) <= names for a in atoms], dtype=bool)


def union_vocabulary(scenes: Sequence[Scene]) -> Vocabulary:
    """The vocabulary of :func:`union_scene` (a scene's own when every scene is the same: LIBERO-spatial's)."""
    return build_vocabulary(union_scene(scenes))


def vocabulary_of(suite: str, scenes: Sequence[Scene]) -> SuiteVocabulary:
    """The union vocabulary of ``scenes`` (one per task) and each task's defined mask."""
    vocab = union_vocabulary(scenes)
    return SuiteVocabulary(
        suite=suite,
        vocabulary=vocab,
        scenes=tuple(scenes),
        object_defined=np.stack([defined_mask(vocab.object_atoms, s) for s in scenes]),
        action_defined=np.stack([defined_mask(vocab.action_atoms, s) for s in scenes]),
    )


def suite_vocabulary(suite: SuiteName, assets: str | Path | None = None) -> SuiteVocabulary:
    """The union vocabulary of every task of ``suite`` (read from the BDDL files; no simulator)."""
    from vlaprobe.envs.bddl_scene import assets_folder, scene_from_problem, task_bddl
    from vlaprobe.envs.libero import suite_tasks

    folder = assets_folder(assets, suite)
    scenes = [scene_from_problem(task_bddl(suite, i), folder) for i, _ in suite_tasks(suite)]
    return vocabulary_of(suite, scenes)


def tasks_defined(
    suite: SuiteName, atoms: Sequence[str], tasks: Sequence[int], assets: str | Path | None = None
) -> np.ndarray:
    """(len(tasks), atoms) bool: which of ``atoms`` each task of ``suite`` defines, from the tasks' BDDL scenes
    (an atom over an object or region absent from the task is undefined there). Each task is read once."""
    from vlaprobe.envs.bddl_scene import task_scene

    masks = {t: defined_mask(atoms, task_scene(suite, t, assets)) for t in dict.fromkeys(tasks)}
    return np.stack([masks[t] for t in tasks]) if len(tasks) else np.zeros((0, len(atoms)), bool)
