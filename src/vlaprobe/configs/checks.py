"""Range checks of the configs, run before any long work: one line naming the flag as the user typed it.

One function per command's config; ``prefix`` is the flag prefix under which that config's fields appear
(``vlaprobe run`` nests them: ``--train.probe.lr``, ``--collect.env.max-steps``). The policy's flags have no
prefix except in ``model-info`` (``--seed``, ``--model``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

from vlaprobe.errors import VlaprobeError

if TYPE_CHECKING:
    from vlaprobe.configs.collect import CollectConfig
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.configs.report import ReportConfig
    from vlaprobe.configs.run import RunConfig
    from vlaprobe.configs.serve import ServeConfig
    from vlaprobe.configs.train import TrainConfig

MAX_SEED = 2**32 - 8
"""Seeds must fit numpy's and torch's generators with the offsets added per stage (split, probe, ...)."""


def _flag(prefix: str, name: str) -> str:
    return "--" + prefix + name.replace("_", "-")


def _at_least(value: int | None, low: int, flag: str, fix: str = "") -> None:
    if value is not None and value < low:
        raise VlaprobeError(f"{flag} must be at least {low}, got {value}{fix}")


def _between(value: float, low: float, high: float, flag: str, closed: bool = False) -> None:
    """``low < value < high`` (``closed``: ``low <= value <= high``), finite."""
    inside = low <= value <= high if closed else low < value < high
    if not (math.isfinite(value) and inside):
        bounds = f"[{low:g}, {high:g}]" if closed else f"({low:g}, {high:g})"
        raise VlaprobeError(f"{flag} must be a number in {bounds}, got {value}")


def check_seed(value: int, flag: str) -> None:
    """A seed every generator takes."""
    if not 0 <= value <= MAX_SEED:
        raise VlaprobeError(f"{flag} must be between 0 and {MAX_SEED}, got {value}")


def check_train(cfg: TrainConfig, prefix: str = "") -> None:
    """The options of ``vlaprobe train``."""
    f = lambda name: _flag(prefix, name)  # noqa: E731
    if not cfg.heads:
        raise VlaprobeError(f"{f('heads')} needs at least one head, e.g. {f('heads')} object action")
    bad_layers = [i for i in cfg.layers if i < 0]
    if bad_layers:
        raise VlaprobeError(f"{f('layers')} takes hidden-state indices 0, 1, ...; got {bad_layers}")
    _between(cfg.min_frequency, 0, 1, f("min_frequency"), closed=True)
    _between(cfg.max_frequency, 0, 1, f("max_frequency"), closed=True)
    if cfg.min_frequency >= cfg.max_frequency:
        raise VlaprobeError(
            f"{f('min_frequency')} {cfg.min_frequency:g} must be below {f('max_frequency')} "
            f"{cfg.max_frequency:g} (atoms outside that range are dropped: none would be left)"
        )
    _at_least(cfg.split.folds, 1, f("split.folds"))
    if cfg.split.folds == 1:
        _between(cfg.split.test_fraction, 0, 1, f("split.test_fraction"))
    p = cfg.probe
    _at_least(p.batch_size, 1, f("probe.batch_size"))
    _at_least(p.epochs, 0, f("probe.epochs"))
    _at_least(p.min_updates, 0, f("probe.min_updates"))
    if p.epochs == 0 and p.min_updates == 0:
        raise VlaprobeError(
            f"{f('probe.epochs')} 0 with {f('probe.min_updates')} 0 would save untrained probes; "
            "give one of them a positive value"
        )
    if not (math.isfinite(p.lr) and p.lr > 0):
        raise VlaprobeError(f"{f('probe.lr')} must be a positive finite number, got {p.lr}")
    if not (math.isfinite(p.weight_decay) and p.weight_decay >= 0):
        raise VlaprobeError(f"{f('probe.weight_decay')} must be 0 or a positive number, got {p.weight_decay}")
    _between(p.threshold, 0, 1, f("probe.threshold"))
    _at_least(cfg.bootstrap, 0, f("bootstrap"))
    _at_least(cfg.auprc_bootstrap, 0, f("auprc_bootstrap"))
    if cfg.shuffled_control:
        _at_least(
            cfg.shuffled_permutations, 1, f("shuffled_permutations"), " (or pass --no-shuffled-control)"
        )
    check_seed(cfg.seed, f("seed"))


def check_env(env: EnvConfig, prefix: str = "env.") -> None:
    """Simulator settings."""
    _at_least(env.max_steps, 1, _flag(prefix, "max_steps"))
    _at_least(env.image_size, 16, _flag(prefix, "image_size"))
    _at_least(env.settle_steps, 0, _flag(prefix, "settle_steps"))


def check_policy(policy: PolicyConfig, prefix: str = "") -> None:
    """The policy's flags (unprefixed everywhere but ``model-info``: ``--policy.seed``)."""
    if not policy.model:
        raise VlaprobeError(
            f"{_flag(prefix, 'model')} needs 'tiny-libero', 'tiny' or an OpenVLA checkpoint folder, got ''"
        )
    check_seed(policy.seed, _flag(prefix, "seed"))


def check_tasks(tasks: tuple[int, ...], suite: str, flag: str) -> list[int]:
    """Every selected task exists in ``suite`` (read from LIBERO's task list: no assets, no model); the suite's
    task indices."""
    from vlaprobe.envs.libero import suite_tasks

    known = [i for i, _ in suite_tasks(suite)]
    unknown = [t for t in tasks if t not in known]
    if unknown:
        raise VlaprobeError(
            f"{flag} {unknown} do not exist; {suite} has tasks 0-{max(known)} (see `vlaprobe tasks`)"
        )
    return known


def check_collect(cfg: CollectConfig, prefix: str = "") -> None:
    """The options of ``vlaprobe collect`` that need no model or store to check."""
    f = lambda name: _flag(prefix, name)  # noqa: E731
    _at_least(cfg.episodes_per_task, 1, f("episodes_per_task"))
    _at_least(cfg.workers, 1, f("workers"))
    _at_least(cfg.max_tries_per_task, 1, f("max_tries_per_task"))
    _at_least(cfg.first_init, 0, f("first_init"))
    _at_least(cfg.post_success_steps, 0, f("post_success_steps"))
    _at_least(cfg.threads, 1, f("threads"), " (or leave it out for the default)")
    check_tasks(cfg.tasks, cfg.env.suite, f("tasks"))
    if not (math.isfinite(cfg.ray_gpus_per_worker) and cfg.ray_gpus_per_worker >= 0):
        raise VlaprobeError(f"{f('ray_gpus_per_worker')} must be 0 or more, got {cfg.ray_gpus_per_worker}")
    check_env(cfg.env, prefix + "env.")
    check_policy(cfg.policy)


def check_serve(cfg: ServeConfig) -> None:
    """The options of ``vlaprobe serve`` checked before the model loads (the server checks its own limits)."""
    from vlaprobe.files import check_output_folder

    check_seed(cfg.seed, "--seed")
    _at_least(cfg.post_success_steps, 0, "--post-success-steps")
    check_env(cfg.env)
    if cfg.recordings is not None:  # a folder the user named (the default sits beside the probes)
        check_output_folder(cfg.recordings, "--recordings")


def check_report(cfg: ReportConfig, prefix: str = "") -> None:
    """The options of ``vlaprobe report``."""
    if not 10 <= cfg.dpi <= 1200:
        raise VlaprobeError(f"{_flag(prefix, 'dpi')} must be between 10 and 1200, got {cfg.dpi}")


def check_run(cfg: RunConfig) -> None:
    """Every stage of ``vlaprobe run``, and what the stages need of each other, before collecting."""
    check_collect(cfg.collect, "collect.")
    check_train(cfg.train, "train.")
    check_report(cfg.report, "report.")
    if cfg.control_model:
        check_policy(dataclasses.replace(cfg.collect.policy, model=cfg.control_model), "control-")
        if cfg.collect.policy.pooling == "action_tokens":
            raise VlaprobeError(
                '--control-model needs a prompt-pass pooling (not "action_tokens"); pass --control-model "" to skip it'
            )
    c = cfg.collect
    if c.episodes_per_task < 2 and not c.keep_failed:
        raise VlaprobeError(
            f"--collect.episodes-per-task {c.episodes_per_task} leaves no task with 2 episodes, so nothing can be "
            "held out to test the probes; use --collect.episodes-per-task 2 or more"
        )
    from vlaprobe.envs.libero import suite_tasks  # check_collect has checked the selected tasks

    episodes = len(c.tasks or suite_tasks(c.env.suite)) * c.episodes_per_task
    if cfg.train.split.folds > episodes and not c.keep_failed:
        raise VlaprobeError(
            f"--train.split.folds {cfg.train.split.folds} needs at least that many episodes; this run keeps "
            f"{episodes}: lower --train.split.folds or collect more"
        )
