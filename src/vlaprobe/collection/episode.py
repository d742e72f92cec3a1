"""The episode schema: what a stored episode holds, typed once, used by the writer and every reader.

:class:`EpisodeSteps` are the per-step columns (one row per observation), :class:`EpisodeAttrs` the episode
attributes besides :class:`~vlaprobe.collection.store.EpisodeInfo`. The collection worker fills them from the
step loop's records; ``ActivationStore.episode(key)`` reads them back (:class:`StoredEpisode`), and
:func:`stored_records` turns a stored episode into the same :class:`~vlaprobe.rollout.StepRecord` a live
episode yields (what a store does not keep is None). ``docs/collection.md`` maps them to the zarr arrays.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from vlaprobe.files import Json, JsonObject
from vlaprobe.rollout import StepRecord
from vlaprobe.rollout.faults import FaultMark
from vlaprobe.rollout.perturb import KIND_CODE
from vlaprobe.rollout.takeover import Takeovers
from vlaprobe.symbols import Articulation, Goal, Scene, WorldState

STEP_DTYPES: dict[str, type] = {
    "hidden": np.float16,
    "object_atoms": bool,
    "action_atoms": bool,
    "image": np.uint8,
    "proprio": np.float32,
    "action": np.float32,
    "predicted_action": np.float32,
    "action_tokens": np.int32,
    "step": np.int32,
}
"""The per-step arrays of an episode and their stored dtypes (besides ``world/*`` and ``perturbation``)."""
OPTIONAL_STEP_ARRAYS = ("perturbation", "expert_action")
"""Per-step arrays only some stores hold (see :class:`EpisodeSteps`)."""
KIND_NAME = {code: kind for kind, code in KIND_CODE.items()}


@dataclass
class EpisodeSteps:
    """The per-step columns of one episode, rows in time order (array names as stored)."""

    hidden: np.ndarray
    """float16 (layers, T, hidden) or (layers, T, 7, hidden): layers first, one chunk per layer."""
    object_atoms: np.ndarray
    """bool (T, object atoms), names in the store's ``atom_names["object"]``."""
    action_atoms: np.ndarray
    """bool (T, action atoms)."""
    image: np.ndarray
    """uint8 (T, 224, 224, 3): the image as the model saw it (upright)."""
    proprio: np.ndarray
    """float32 (T, 9): end-effector position, quaternion xyzw, finger joint positions."""
    action: np.ndarray
    """float32 (T, 7): the executed action; NaN on a terminal row."""
    predicted_action: np.ndarray
    """float32 (T, 7): the observer model's own action."""
    action_tokens: np.ndarray
    """int32 (T, 7): the token ids of the predicted action."""
    step: np.ndarray
    """int32 (T,): the simulator's step counter since the settled reset."""
    world: list[WorldState]
    """The simulator snapshots the atoms were computed from (stored as ``world/<field>``)."""
    perturbation: np.ndarray | None = None
    """int8 (T,): ``rollout.perturb.KIND_CODE`` of the perturbation that changed a row (0: none); only in
    stores collected with ``--perturb``."""
    expert_action: np.ndarray | None = None
    """float32 (T, 7): the scripted expert's action for each row, the label ``vlaprobe finetune`` learns
    from (NaN on a terminal row); only in stores collected with ``--driver dagger``."""

    @property
    def length(self) -> int:
        return len(self.world)

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays by store name, as the writer takes them."""
        out = {name: getattr(self, name) for name in STEP_DTYPES}
        out.update(world_arrays(self.world))
        for name in OPTIONAL_STEP_ARRAYS:
            if (value := getattr(self, name)) is not None:
                out[name] = value
        return out

    @classmethod
    def from_records(cls, records: Iterable[StepRecord], codes: Sequence[int] | None = None) -> EpisodeSteps:
        """The columns of the step loop's records (``codes``: the perturbation code of each row, if any)."""
        rows = StepRows()
        for r in records:
            rows.add(r)
        return rows.steps(codes)

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> EpisodeSteps:
        """The columns of a stored episode (reads every array)."""
        return cls(
            **{name: np.asarray(arrays[name]) for name in STEP_DTYPES},
            world=world_states(arrays),
            **{k: np.asarray(arrays[k]) if k in arrays else None for k in OPTIONAL_STEP_ARRAYS},  # type: ignore[arg-type]
        )


class StepRows:
    """Buffers the step loop's records row by row (only the stored columns, not the raw renders)."""

    def __init__(self) -> None:
        self._cols: dict[str, list[np.ndarray | int]] = {name: [] for name in STEP_DTYPES}
        self._world: list[WorldState] = []
        self._expert: list[np.ndarray | None] = []

    def add(self, r: StepRecord) -> None:
        for name, values in self._cols.items():
            values.append(_value(r, name))
        self._world.append(_world(r))
        self._expert.append(r.expert_action)

    def steps(self, codes: Sequence[int] | None = None) -> EpisodeSteps:
        """The columns of the rows added (``codes``: the perturbation code of each row, if any)."""
        cols: dict[str, np.ndarray] = {
            name: np.asarray(np.stack(self._cols[name]), dtype=dtype) for name, dtype in STEP_DTYPES.items()
        }
        cols["hidden"] = np.ascontiguousarray(np.moveaxis(cols["hidden"], 0, 1))  # (layers, T, ...)
        perturbation = None if codes is None else np.asarray(codes, dtype=np.int8)
        labelled = [a for a in self._expert if a is not None]
        expert = None
        if labelled:  # a row the expert did not label (a success at reset) has none: NaN like a terminal row
            nan = np.full(7, np.nan)
            expert = np.stack([nan if a is None else a for a in self._expert]).astype(np.float32)
        return EpisodeSteps(**cols, world=self._world, perturbation=perturbation, expert_action=expert)


def _value(r: StepRecord, name: str) -> np.ndarray | int:
    if name == "image":
        return r.model_image
    if name == "hidden":
        return np.asarray(r.hidden, dtype=np.float16)
    value = getattr(r, name)
    if value is None:
        raise ValueError(f"step record {r.t} has no {name}; only the step loop's records are stored")
    return value


def _world(r: StepRecord) -> WorldState:
    if r.world is None:
        raise ValueError(f"step record {r.t} has no world state; only the step loop's records are stored")
    return r.world


@dataclass(frozen=True)
class PerturbationMark:
    """A perturbation that happened in an episode."""

    kind: str
    """``rollout.perturb`` kind: "drop", "displace", "knock_off"."""
    row: int
    """The first row it changed."""


@dataclass(frozen=True)
class PerturbationMiss:
    """A perturbation an episode drew that did not happen, and why."""

    kind: str
    """``rollout.perturb`` kind."""
    row: int | None
    """The row at which it was given up; None when its moment never came."""
    reason: str
    """"<class>: <details>", the class one of "too late" (a knock-off with too few actions left to recover),
    "no free spot" (none within reach), "never due" (e.g. the task never succeeded)."""


@dataclass
class EpisodeAttrs:
    """The attributes of an episode besides its :class:`~vlaprobe.collection.store.EpisodeInfo`."""

    instruction: str
    """The task's language instruction ("" if not recorded)."""
    scene: Scene | None
    """The typed objects of the task (rebuilds the episode's ``Labeler``); None if not recorded."""
    goal: Goal | None
    """The task's pick-and-place goal; None if not recorded."""
    seconds: float | None = None
    """Wall time of the step loop."""
    inits: str | None = None
    """"sampled" or "sampled-swap" for an episode from a sampled placement (``--inits``); None: a fixed init
    state."""
    placement_seed: int | None = None
    """Seed of the sampled placement."""
    placement_draws: int | None = None
    """Draws the sampler took to find a placement whose init conditions hold."""
    rejected_samples: list[Json] | None = None
    """The rejected draws (their reasons)."""
    placement_regions: dict[str, str] | None = None
    """``--inits sampled-swap``: object -> the table region it started in, where it differs from the BDDL."""
    perturbations: list[PerturbationMark] | None = None
    """The perturbations that happened (``--perturb``); None: collected without."""
    perturbations_missed: list[PerturbationMiss] | None = None
    """The perturbations drawn for the episode that did not happen, with why (``--perturb``); None: collected
    without, or before they were recorded."""
    faults: list[FaultMark] | None = None
    """The faults injected into the expert that hit this episode (``--expert-faults``); None: collected
    without."""
    failure_step: int | None = None
    """The row from which the episode's failure was certain (an injected fault: the expert gave up or let go on
    a wrong target); None where unknown."""
    takeovers: Takeovers | None = None
    """When and why the scripted expert took over from the policy, and for how many steps (``--takeover``);
    None: collected without."""
    extra: JsonObject = field(default_factory=dict)
    """Attributes of other writers, kept as read."""

    def to_json(self) -> JsonObject:
        """The group attributes as stored (a field left None is not written)."""
        out: JsonObject = {"instruction": self.instruction}
        if self.scene is not None:
            out["scene"] = dataclasses.asdict(self.scene)
        if self.goal is not None:
            out["goal"] = dataclasses.asdict(self.goal)
        if self.seconds is not None:
            out["seconds"] = self.seconds
        for name in ("inits", "placement_seed", "placement_draws", "rejected_samples", "placement_regions"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        if self.perturbations is not None:
            out["perturbations"] = [{"kind": p.kind, "row": p.row} for p in self.perturbations]
        if self.perturbations_missed is not None:
            out["perturbations_missed"] = [
                {"kind": m.kind, "row": m.row, "reason": m.reason} for m in self.perturbations_missed
            ]
        if self.faults is not None:
            out["faults"] = [{"kind": f.kind, "row": f.row} for f in self.faults]
            out["failure_step"] = self.failure_step
        if self.takeovers is not None:
            out["takeovers"] = self.takeovers.to_json()
        return {**out, **self.extra}

    @classmethod
    def from_json(cls, attrs: Mapping[str, Json]) -> EpisodeAttrs:
        """The attributes of a stored episode (the :class:`EpisodeInfo` fields among them are ignored)."""
        from vlaprobe.collection.store import EpisodeInfo

        scene = _scene(attrs["scene"]) if "scene" in attrs else None
        goal = Goal(**attrs["goal"]) if "goal" in attrs else None
        known = {f.name for f in dataclasses.fields(cls)} | {f.name for f in dataclasses.fields(EpisodeInfo)}
        marks, faults = attrs.get("perturbations"), attrs.get("faults")
        misses = attrs.get("perturbations_missed")
        return cls(
            instruction=str(attrs.get("instruction", "")),
            scene=scene,
            goal=goal,
            seconds=attrs.get("seconds"),
            inits=attrs.get("inits"),
            placement_seed=attrs.get("placement_seed"),
            placement_draws=attrs.get("placement_draws"),
            rejected_samples=attrs.get("rejected_samples"),
            placement_regions=attrs.get("placement_regions"),
            perturbations=None
            if marks is None
            else [PerturbationMark(str(m["kind"]), int(m["row"])) for m in marks],
            perturbations_missed=None
            if misses is None
            else [
                PerturbationMiss(
                    str(m["kind"]), None if m["row"] is None else int(m["row"]), str(m["reason"])
                )
                for m in misses
            ],
            faults=None if faults is None else [FaultMark(str(m["kind"]), int(m["row"])) for m in faults],
            failure_step=None if attrs.get("failure_step") is None else int(attrs["failure_step"]),
            takeovers=None if attrs.get("takeovers") is None else Takeovers.from_json(attrs["takeovers"]),
            extra={k: v for k, v in attrs.items() if k not in known},
        )


def world_arrays(states: Sequence[WorldState]) -> dict[str, np.ndarray]:
    """Stack per-step :class:`~vlaprobe.symbols.WorldState` snapshots into ``world/<field>`` arrays (steps first)."""
    fields = [f.name for f in dataclasses.fields(states[0])]
    return {f"world/{name}": np.stack([np.asarray(getattr(s, name)) for s in states]) for name in fields}


def world_states(arrays: Mapping[str, np.ndarray]) -> list[WorldState]:
    """The per-step :class:`~vlaprobe.symbols.WorldState` snapshots stored with an episode."""
    columns = {f.name: arrays[f"world/{f.name}"] for f in dataclasses.fields(WorldState)}
    length = len(next(iter(columns.values())))
    # A (steps,) column holds a scalar field (fovy, gripper command); array fields are at least (steps, k).
    return [
        WorldState(**{name: float(c[t]) if c.ndim == 1 else c[t] for name, c in columns.items()})  # type: ignore[arg-type]
        for t in range(length)
    ]


def stored_scene(attrs: Mapping[str, Json]) -> tuple[Scene, Goal]:
    """(Scene, Goal) of an episode from its attributes, to rebuild its :class:`~vlaprobe.symbols.Labeler`."""
    return _scene(attrs["scene"]), Goal(**attrs["goal"])


def _scene(stored: Mapping[str, Json]) -> Scene:
    """A stored scene; fields added since it was stored (receptacles, doors, close and off rules: issue #35) take
    their defaults, which is what those scenes had."""
    kwargs: JsonObject = {}
    for f in dataclasses.fields(Scene):
        has_default = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
        if f.name not in stored and has_default:
            continue
        value = stored[f.name]
        if f.name.endswith("articulation"):
            value = tuple(Articulation(**a) for a in value)
        kwargs[f.name] = tuple(value) if isinstance(value, list) else value
    return Scene(**kwargs)


def stored_records(arrays: Mapping[str, np.ndarray], success_step: int | None) -> Iterator[StepRecord]:
    """A stored episode's rows as the step loop's records: hidden states as float32 (layers, ...), ``success``
    from the episode's success step; the raw render, the world state and the timings are not stored (None).
    Reads the columns the live monitor shows, each once."""
    hidden = np.asarray(arrays["hidden"])  # (layers, T, ...) as stored
    cols = {k: np.asarray(arrays[k]) for k in ("image", "object_atoms", "action_atoms", "action")}
    predicted = np.asarray(arrays["predicted_action"])
    optional = {
        k: np.asarray(arrays[k]) if k in arrays else None for k in ("proprio", "action_tokens", "step")
    }
    codes = np.asarray(arrays["perturbation"]) if "perturbation" in arrays else None
    expert = np.asarray(arrays["expert_action"]) if "expert_action" in arrays else None
    n = len(cols["image"])
    for t in range(n):
        kind = KIND_NAME.get(int(codes[t]), "") if codes is not None else ""
        yield StepRecord(
            t=t,
            step=int(optional["step"][t]) if optional["step"] is not None else t,
            raw_image=None,
            model_image=cols["image"][t],
            hidden=hidden[:, t].astype(np.float32),
            object_atoms=cols["object_atoms"][t],
            action_atoms=cols["action_atoms"][t],
            world=None,
            proprio=optional["proprio"][t] if optional["proprio"] is not None else None,
            action=cols["action"][t],
            predicted_action=predicted[t],
            action_tokens=optional["action_tokens"][t] if optional["action_tokens"] is not None else None,
            success=success_step is not None and t >= success_step,
            terminal=t == n - 1,
            perturbed=bool(kind),
            perturbation="drop" if kind == "drop" else ("move" if kind else ""),
            timings=None,
            expert_action=expert[t] if expert is not None else None,
        )
