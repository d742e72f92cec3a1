"""Range checks of the configs, run before any long work: one line naming the flag as the user typed it.

One function per command's config; ``prefix`` is the flag prefix under which that config's fields appear
(``vlaprobe run`` nests them: ``--train.probe.lr``, ``--collect.env.max-steps``). The policy's flags have no
prefix except in ``model-info`` (``--seed``, ``--model``).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import FolderKind

if TYPE_CHECKING:
    from vlaprobe.configs.collect import CollectConfig
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.configs.report import ReportConfig
    from vlaprobe.configs.run import RunConfig
    from vlaprobe.configs.serve import ServeConfig
    from vlaprobe.configs.takeover import TakeoverConfig
    from vlaprobe.configs.train import TrainConfig

MAX_SEED = 2**32 - 8
"""Seeds must fit numpy's and torch's generators with the offsets added per stage (split, probe, ...)."""


REPORT_SUFFIXES = (".html", ".json", ".png", ".svg", ".csv")


def _legacy_report(folder: Path) -> bool:
    """A report folder written before markers: its page, its tables and at least one figure (png and svg)."""
    names = {p.name for p in folder.iterdir() if not p.name.startswith(".")}
    figures = {n[:-4] for n in names if n.endswith(".png")} & {n[:-4] for n in names if n.endswith(".svg")}
    return {"index.html", "tables.json"} <= names and bool(figures)


REPORT_FOLDER = FolderKind(
    "report",
    known=lambda name: name.endswith(REPORT_SUFFIXES),
    signature=_legacy_report,
    fix="choose an empty or new folder (the default is report/ beside the probes)",
)
"""The folder ``vlaprobe report`` writes: its page, tables and figures (png, svg, json, csv)."""
RUN_FILES = frozenset({"activations", "control", "probes", "report", "config.json", "results.json", "live"})
RUN_FOLDER = FolderKind(
    "run",
    known=lambda name: name in RUN_FILES,
    signature=lambda folder: (
        (folder / "activations" / "zarr.json").is_file() or (folder / "probes" / "probes.json").is_file()
    ),
    fix="choose an empty or new folder, or an earlier run's folder to resume it",
)
"""A run folder: the stages' folders, the control observer's ``control/``, the run's config, ``results.json``
and ``live/`` (recordings of ``vlaprobe serve``)."""
MAX_IMAGE_SIZE = 4096
"""Largest render side (pixels) of ``--env.image-size``."""
LIBERO_HORIZON = 1000
"""Simulator steps LIBERO's robosuite environment allows per reset (its ``horizon``), settling included: a
longer episode fails with "executing action in terminated episode"."""


def step_limit(settle_steps: int) -> int:
    """The largest step budget the simulator can run after ``settle_steps`` settling steps."""
    return LIBERO_HORIZON - max(0, settle_steps)


def _flag(prefix: str, name: str) -> str:
    return "--" + prefix + name.replace("_", "-")


MAX_COUNT = 2**31 - 1
"""Largest count any flag takes (steps, epochs, workers...): beyond it a value is a typo, not a plan."""


def at_least(value: int | None, low: int, flag: str, fix: str = "") -> None:
    if value is not None and value < low:
        raise VlaprobeError(f"{flag} must be at least {low}, got {value}{fix}")
    if value is not None and value > MAX_COUNT:
        raise VlaprobeError(f"{flag} must be at most {MAX_COUNT}, got {value}")


def _between(value: float, low: float, high: float, flag: str, closed: bool = False) -> None:
    """``low < value < high`` (``closed``: ``low <= value <= high``), finite."""
    inside = low <= value <= high if closed else low < value < high
    if not (math.isfinite(value) and inside):
        bounds = f"[{low:g}, {high:g}]" if closed else f"({low:g}, {high:g})"
        raise VlaprobeError(f"{flag} must be a number in {bounds}, got {value}")


def check_device(name: str, flag: str) -> None:
    """A torch device name the trainer can use (before a run collects for hours)."""
    from vlaprobe.devices import resolve_device

    try:
        resolve_device(name)
    except VlaprobeError as exc:
        raise VlaprobeError(f"{flag}: {exc}") from None


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
    at_least(cfg.split.folds, 1, f("split.folds"))
    if cfg.split.folds == 1:
        _between(cfg.split.test_fraction, 0, 1, f("split.test_fraction"))
    p = cfg.probe
    if not p.c_grid or not all(math.isfinite(c) and c > 0 for c in p.c_grid):
        raise VlaprobeError(f"{f('probe.c_grid')} needs positive finite values, got {list(p.c_grid)}")
    if len(p.c_grid) > 1:
        at_least(p.cv_folds, 2, f("probe.cv_folds"), " (or give one value to --probe.c-grid)")
    if not (math.isfinite(p.c_tolerance) and p.c_tolerance >= 0):
        raise VlaprobeError(f"{f('probe.c_tolerance')} must be a finite number >= 0, got {p.c_tolerance}")
    if not (math.isfinite(p.tol) and p.tol > 0):
        raise VlaprobeError(f"{f('probe.tol')} must be a positive finite number, got {p.tol}")
    at_least(p.max_iter, 1, f("probe.max_iter"))
    at_least(p.history, 1, f("probe.history"))
    if not (math.isfinite(p.c_without_cv) and p.c_without_cv > 0):
        raise VlaprobeError(
            f"{f('probe.c_without_cv')} must be a positive finite number, got {p.c_without_cv}"
        )
    if not (math.isfinite(p.memory_mb) and p.memory_mb > 0):
        raise VlaprobeError(f"{f('probe.memory_mb')} must be a positive finite number, got {p.memory_mb}")
    _between(p.threshold, 0, 1, f("probe.threshold"))
    check_device(p.device, f("probe.device"))
    at_least(cfg.bootstrap, 0, f("bootstrap"))
    at_least(cfg.auprc_bootstrap, 0, f("auprc_bootstrap"))
    if cfg.shuffled_control:
        at_least(cfg.shuffled_permutations, 1, f("shuffled_permutations"), " (or pass --no-shuffled-control)")
    check_seed(cfg.seed, f("seed"))


def check_env(env: EnvConfig, prefix: str = "env.") -> None:
    """Simulator settings."""
    at_least(env.max_steps, 1, _flag(prefix, "max_steps"))
    at_least(env.image_size, 16, _flag(prefix, "image_size"))
    if env.image_size > MAX_IMAGE_SIZE:
        raise VlaprobeError(
            f"{_flag(prefix, 'image_size')} must be at most {MAX_IMAGE_SIZE}, got {env.image_size}"
        )
    at_least(env.settle_steps, 0, _flag(prefix, "settle_steps"))
    check_step_budget(
        env.max_steps, env.settle_steps, _flag(prefix, "max_steps"), _flag(prefix, "settle_steps")
    )


def check_step_budget(
    max_steps: int, settle_steps: int, flag: str, settle_flag: str = "--env.settle-steps"
) -> None:
    """A budget the simulator can run to its end (LIBERO's horizon counts the settling steps too)."""
    limit = step_limit(settle_steps)
    if max_steps > limit:
        raise VlaprobeError(
            f"{flag} {max_steps} is more than the simulator runs: LIBERO ends an episode after {LIBERO_HORIZON} "
            f"steps including {settle_flag} {settle_steps}; use at most {limit}"
        )


def check_policy(policy: PolicyConfig, prefix: str = "") -> None:
    """The policy's flags (unprefixed everywhere but ``model-info``: ``--policy.seed``)."""
    if not policy.model:
        raise VlaprobeError(
            f"{_flag(prefix, 'model')} needs 'tiny-libero', 'tiny' or an OpenVLA checkpoint folder, got ''"
        )
    check_seed(policy.seed, _flag(prefix, "seed"))


def check_collect(cfg: CollectConfig, prefix: str = "") -> None:
    """The options of ``vlaprobe collect`` that need no model, store or suite to check (the suite's:
    ``vlaprobe.collection.collect.check_collect_suite``)."""
    f = lambda name: _flag(prefix, name)  # noqa: E731
    at_least(cfg.episodes_per_task, 1, f("episodes_per_task"))
    at_least(cfg.workers, 1, f("workers"))
    at_least(cfg.max_tries_per_task, 1, f("max_tries_per_task"))
    at_least(cfg.first_init, 0, f("first_init"))
    at_least(cfg.post_success_steps, 0, f("post_success_steps"))
    at_least(cfg.threads, 1, f("threads"), " (or leave it out for the default)")
    _between(cfg.dagger_beta, 0.0, 1.0, f("dagger_beta"), closed=True)
    if cfg.dagger_beta and cfg.driver != "dagger":
        raise VlaprobeError(
            f"{f('dagger_beta')} applies to --driver dagger only; drop it or add --driver dagger"
        )
    if cfg.expert_faults and cfg.driver != "expert":
        raise VlaprobeError(
            f"{f('expert_faults')} changes the scripted expert's actions; use it with --driver expert"
        )
    if not (math.isfinite(cfg.ray_gpus_per_worker) and cfg.ray_gpus_per_worker >= 0):
        raise VlaprobeError(f"{f('ray_gpus_per_worker')} must be 0 or more, got {cfg.ray_gpus_per_worker}")
    check_takeover(cfg.intervention, cfg.driver, "collect", prefix)
    check_env(cfg.env, prefix + "env.")
    check_policy(cfg.policy)


def check_takeover(cfg: TakeoverConfig, driver: str, command: str, prefix: str = "") -> None:
    """``--takeover`` and its settings (``command``: "collect" or "serve", whose drivers and options differ;
    ``prefix``: the driver's flag prefix, the takeover's flags have none)."""
    if cfg.takeover == "none":
        return
    flag = _flag(prefix, "driver")
    drivers = f"{flag} policy" + (" or dagger" if command == "collect" else "")
    if driver == "expert":
        raise VlaprobeError(
            f"--takeover {cfg.takeover} hands the policy's control to the scripted expert, but {flag} expert "
            f"has no policy; add {drivers}"
        )
    for name in ("takeover_steps", "takeover_most", "takeover_stall", "takeover_hold", "takeover_count"):
        at_least(getattr(cfg, name), 1, _flag("", name))
    if not cfg.takeover_on:
        raise VlaprobeError("--takeover-on needs at least one of stall, regression, dropped, violation")
    if len(set(cfg.takeover_on)) != len(cfg.takeover_on):
        raise VlaprobeError(f"--takeover-on names a kind twice ({' '.join(cfg.takeover_on)}); give each once")
    if command == "serve" and cfg.takeover_match is not None:
        raise VlaprobeError(
            "--takeover-match matches a collection's alarm run; serve --takeover random takes --takeover-count"
        )
    if command == "serve" and cfg.takeover_probes is not None:
        raise VlaprobeError(
            "--takeover-probes is collect's; serve's alarm reads the predictions of its --probes (drop it)"
        )


def check_serve(cfg: ServeConfig) -> None:
    """The options of ``vlaprobe serve`` checked before the model loads (the server checks its own limits and
    the suite's)."""
    from vlaprobe.files import check_output_folder

    check_seed(cfg.seed, "--seed")
    if not 0 <= cfg.port <= 65535:
        raise VlaprobeError(f"--port must be between 0 and 65535 (0: any free port), got {cfg.port}")
    at_least(cfg.post_success_steps, 0, "--post-success-steps")
    at_least(
        cfg.max_message_bytes, MIN_MESSAGE_BYTES, "--max-message-bytes", " (a start command is ~100 bytes)"
    )
    at_least(cfg.threads, 0, "--threads", " (0: the default)")
    if not (math.isfinite(cfg.image_hz) and cfg.image_hz > 0):
        raise VlaprobeError(f"--image-hz must be a positive number, got {cfg.image_hz}")
    _between(cfg.replay_hz, REPLAY_HZ[0], REPLAY_HZ[1], "--replay-hz", closed=True)
    check_takeover(cfg.intervention, cfg.driver, "serve")
    check_env(cfg.env)
    if cfg.recordings is not None:  # a folder the user named (the default sits beside the probes)
        check_output_folder(cfg.recordings, "--recordings")
    if cfg.token is not None and cfg.token_file is not None:
        raise VlaprobeError("--token and --token-file both given; pass one (or set $VLAPROBE_TOKEN)")
    if cfg.token_file is not None and not cfg.token_file.is_file():
        raise VlaprobeError(
            f"--token-file {cfg.token_file} is not a file; write the secret into a file first"
        )


MIN_MESSAGE_BYTES = 1024
"""Smallest ``--max-message-bytes``: every command of the protocol fits."""
REPLAY_HZ = (0.5, 60.0)
"""Replay pacing bounds, steps per second (``--replay-hz`` and a replay command's ``hz``)."""


def check_report(cfg: ReportConfig, prefix: str = "") -> None:
    """The options of ``vlaprobe report``."""
    if not 10 <= cfg.dpi <= 1200:
        raise VlaprobeError(f"{_flag(prefix, 'dpi')} must be between 10 and 1200, got {cfg.dpi}")


def check_run(cfg: RunConfig) -> None:
    """Every stage of ``vlaprobe run``, and what the stages need of each other, before collecting (what needs
    the suite: ``vlaprobe.pipeline.check_run_suite``)."""
    check_collect(cfg.collect, "collect.")
    check_train(cfg.train, "train.")
    check_report(cfg.report, "report.")
    if cfg.control_model:
        check_policy(dataclasses.replace(cfg.collect.policy, model=cfg.control_model), "control-")
        if cfg.control_model == cfg.collect.policy.model:
            raise VlaprobeError(
                f"--control-model {cfg.control_model} is the observed model itself: the control would compare "
                'the probes with themselves; name another model, or pass --control-model "" to skip it'
            )
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
