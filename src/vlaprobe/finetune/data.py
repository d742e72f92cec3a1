"""Demonstrations from collection stores: the rows to train on, the episode split and the action statistics.

A row is one step of an expert episode: the image exactly as the model saw it (``image``), the executed
action (``action``, LIBERO's convention) turned into OpenVLA's training target (gripper 1 open, 0 closed),
and the episode's instruction. In a store collected with ``--driver dagger`` the target is the scripted
expert's label (``expert_action``) instead: there the model acted, and the expert said what it should have
done. The statistics follow OpenVLA's ``dataset_statistics.json`` (q01/q99 of the
training split's actions; the gripper is left unnormalised by the mask).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vlaprobe.collection.store import ActivationStore, EpisodeInfo, StoredEpisode
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject
from vlaprobe.policies.openvla.actions import training_gripper

NOOP_THRESHOLD = 1e-4
"""A step is idle when its translation + rotation norm is below this and the gripper command is unchanged
(the test LIBERO's ``regenerate_libero_dataset.py`` applies to make the ``*_no_noops`` datasets)."""

ACTION_MASK = [True, True, True, True, True, True, False]
"""Which action dimensions are normalised: all but the gripper (OpenVLA's LIBERO statistics)."""


@dataclass(frozen=True)
class EpisodeRef:
    """One demonstration episode and where it came from."""

    store: int
    """Index of its store in ``--stores``."""
    key: str
    """Episode key in that store (``t03_i12_a00``)."""
    task: int
    """Task index."""
    instruction: str
    """The task's instruction, as the model reads it in the prompt."""


@dataclass
class Demonstrations:
    """Every kept row of the loaded episodes, in episode order."""

    images: np.ndarray
    """uint8 (N, S, S, 3): the images as the model saw them."""
    actions: np.ndarray
    """float64 (N, 7): OpenVLA's training targets (continuous; gripper 1 open, 0 closed)."""
    proprio: np.ndarray | None
    """float32 (N, 9) proprioception when every store has it (statistics only)."""
    episode: np.ndarray
    """int64 (N,): index of each row's episode in ``episodes``."""
    episodes: list[EpisodeRef]
    """The episodes rows refer to."""


@dataclass(frozen=True)
class Split:
    """Rows of the training and validation episodes (whole episodes on each side)."""

    train: np.ndarray
    """Row indices of the training episodes."""
    val: np.ndarray
    """Row indices of the validation episodes (possibly thinned to ``val_max_samples``)."""
    train_episodes: tuple[int, ...]
    """Episode indices in training."""
    val_episodes: tuple[int, ...]
    """Episode indices held out."""


def _instruction(store: ActivationStore, info: EpisodeInfo, arrays: StoredEpisode) -> str:
    text = arrays.attributes.instruction or store.metadata.instructions.get(str(info.task))
    if not text:
        raise VlaprobeError(
            f"store {store.path}: episode {info.key} has no instruction; collect it again with this vlaprobe"
        )
    return str(text)


def keep_rows(
    actions: np.ndarray, success_step: int | None, skip_post_success: bool, drop_noops: bool
) -> np.ndarray:
    """Boolean mask of the rows of one episode that are demonstration steps."""
    keep = np.isfinite(actions).all(axis=1)  # a terminal row has no action (NaN)
    if skip_post_success and success_step is not None:
        keep[success_step:] = False  # the goal was already reached when these actions were taken
    if drop_noops:
        idle = np.linalg.norm(actions[:, :6], axis=1) < NOOP_THRESHOLD
        same_gripper = np.concatenate([[False], actions[1:, 6] == actions[:-1, 6]])
        keep &= ~(idle & (same_gripper | (np.arange(len(actions)) == 0)))
    return keep


def target_array(arrays: StoredEpisode) -> str:
    """The array an episode's training targets come from: the expert's labels where it has them (DAgger),
    else the executed actions."""
    return "expert_action" if "expert_action" in arrays else "action"


def load_demonstrations(
    paths: tuple[Path, ...],
    image_size: int,
    success_only: bool = True,
    skip_post_success: bool = True,
    drop_noops: bool = True,
    tasks: tuple[int, ...] = (),
) -> Demonstrations:
    """Read the demonstration rows of every store (only ``tasks``' episodes when given); a one-line error for
    a store that cannot train a model."""
    stores = [ActivationStore.open(p) for p in paths]
    images, actions, proprio, episode = [], [], [], []
    refs: list[EpisodeRef] = []
    has_proprio = True
    for s_index, store in enumerate(stores):
        # The expert's labels teach wherever the model went: a DAgger store's failed episodes count too.
        only_success = success_only and store.metadata.driver != "dagger"
        infos = store.episodes(success_only=only_success)
        if not infos:
            what = "successful episodes" if only_success else "episodes"
            raise VlaprobeError(f"store {store.path} has no {what}; collect some or pass --no-success-only")
        # A store may hold none of the chosen tasks; only all stores together must.
        infos = [info for info in infos if not tasks or info.task in tasks]
        for info in infos:
            arrays = store.episode(info.key)
            if "image" not in arrays or "action" not in arrays:
                raise VlaprobeError(
                    f"store {store.path} has no images or actions (episode {info.key}); fine-tuning needs a "
                    "store written by `vlaprobe collect`, which records both"
                )
            img = arrays["image"]
            if img.ndim != 4 or img.shape[1:] != (image_size, image_size, 3):
                raise VlaprobeError(
                    f"store {store.path} holds images of shape {list(img.shape[1:])}, the model takes "
                    f"{image_size}x{image_size}x3; collect with a model of the same image size"
                )
            raw = np.asarray(arrays[target_array(arrays)], dtype=np.float64)
            keep = keep_rows(raw, info.success_step, skip_post_success, drop_noops)
            if not keep.any():
                continue
            refs.append(EpisodeRef(s_index, info.key, info.task, _instruction(store, info, arrays)))
            images.append(img[keep])
            actions.append(training_gripper(raw[keep]))
            episode.append(np.full(int(keep.sum()), len(refs) - 1, dtype=np.int64))
            if "proprio" in arrays and has_proprio:
                proprio.append(np.asarray(arrays["proprio"], dtype=np.float32)[keep])
            else:
                has_proprio = False
    if not refs and tasks:
        raise VlaprobeError(
            f"no demonstration of tasks {list(tasks)} in {[str(p) for p in paths]}; pick --tasks the stores "
            "hold (`vlaprobe info STORE` lists them per task)"
        )
    if not refs:
        raise VlaprobeError(f"no demonstration rows left in {[str(p) for p in paths]} after the filters")
    return Demonstrations(
        images=np.concatenate(images),
        actions=np.concatenate(actions),
        proprio=np.concatenate(proprio) if has_proprio else None,
        episode=np.concatenate(episode),
        episodes=refs,
    )


def split_episodes(demos: Demonstrations, val_fraction: float, seed: int, val_max_samples: int = 0) -> Split:
    """Hold out ``val_fraction`` of each task's episodes (at least one of every task with two or more)."""
    rng = np.random.default_rng([seed, 17])
    by_task: dict[int, list[int]] = {}
    for i, ref in enumerate(demos.episodes):
        by_task.setdefault(ref.task, []).append(i)
    train_eps, val_eps = [], []
    for task in sorted(by_task):
        eps = [by_task[task][j] for j in rng.permutation(len(by_task[task]))]
        n_val = 0 if len(eps) < 2 else min(len(eps) - 1, max(1, round(val_fraction * len(eps))))
        val_eps += eps[:n_val]
        train_eps += eps[n_val:]
    train_eps.sort()
    val_eps.sort()
    if not val_eps:
        raise VlaprobeError(
            "the validation split is empty: every task has fewer than 2 episodes; collect at least 2 episodes "
            "of some task (`vlaprobe collect --episodes-per-task 2`)"
        )
    rows = np.arange(len(demos.episode))
    train = rows[np.isin(demos.episode, train_eps)]
    val = rows[np.isin(demos.episode, val_eps)]
    if val_max_samples and len(val) > val_max_samples:
        val = val[np.unique(np.linspace(0, len(val) - 1, val_max_samples).round().astype(np.int64))]
    return Split(train, val, tuple(train_eps), tuple(val_eps))


def _summary(x: np.ndarray) -> dict[str, list[float]]:
    return {
        "mean": x.mean(0).tolist(),
        "std": x.std(0).tolist(),
        "max": x.max(0).tolist(),
        "min": x.min(0).tolist(),
        "q01": np.quantile(x, 0.01, axis=0).tolist(),
        "q99": np.quantile(x, 0.99, axis=0).tolist(),
    }


def dataset_statistics(demos: Demonstrations, rows: np.ndarray, n_episodes: int) -> JsonObject:
    """OpenVLA's per-dataset statistics of ``rows`` (its ``dataset_statistics.json`` entry)."""
    stats: JsonObject = {"action": {**_summary(demos.actions[rows]), "mask": list(ACTION_MASK)}}
    if demos.proprio is not None:
        stats["proprio"] = _summary(demos.proprio[rows].astype(np.float64))
    stats["num_transitions"] = len(rows)
    stats["num_trajectories"] = int(n_episodes)
    return stats
