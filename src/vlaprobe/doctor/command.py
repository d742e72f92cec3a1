"""``vlaprobe doctor``: every check in turn, one line each as it finishes (or one JSON object at the end).

The renderer backends start first, in subprocesses, and are collected last, so their start-up overlaps the
in-process checks. Exit status 0 when no check failed, 1 when one did (:data:`~vlaprobe.doctor.report.Status`).
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import time

from vlaprobe.configs.checks import at_least, check_device, check_env, check_policy
from vlaprobe.configs.doctor import DoctorConfig
from vlaprobe.doctor.libero import assets_checks, libero_check
from vlaprobe.doctor.policy import policy_check
from vlaprobe.doctor.render import renderer_checks, start_backends
from vlaprobe.doctor.report import Check, closing_line, line, ready, timed, timed_all, to_json
from vlaprobe.doctor.system import (
    TOOLS,
    chromium_check,
    disk_check,
    pin_checks,
    python_check,
    tool_check,
    torch_check,
)
from vlaprobe.errors import VlaprobeError


def check_doctor(cfg: DoctorConfig) -> None:
    """The flags, before any check runs (one line, exit 2)."""
    at_least(cfg.episodes, 0, "--episodes")
    if not (math.isfinite(cfg.timeout) and cfg.timeout > 0):
        raise VlaprobeError(f"--timeout must be a positive number of seconds, got {cfg.timeout}")
    if not cfg.renderers:
        raise VlaprobeError("--renderers needs at least one backend: osmesa, egl or glx")
    check_env(cfg.env)
    check_policy(cfg.policy)
    check_device(cfg.policy.device, "--device")


def backend_in_use() -> str:
    """The ``MUJOCO_GL`` backend a run would use: the user's, else the one LIBERO's set-up chooses."""
    from vlaprobe.envs.setup import prepare_libero

    # LIBERO missing: the libero check says so; the renderer is chosen before that is found.
    with contextlib.suppress(VlaprobeError):
        prepare_libero(need_assets=False)
    return os.environ.get("MUJOCO_GL", "egl")


class _Printer:
    """Collects the checks and prints each line as it comes (not with --json)."""

    def __init__(self, quiet: bool) -> None:
        self.checks: list[Check] = []
        self.quiet = quiet

    def add(self, *checks: Check) -> None:
        for check in checks:
            self.checks.append(check)
            if not self.quiet:
                print(line(check), flush=True)


def doctor(cfg: DoctorConfig) -> int:
    """Run every check for ``cfg``'s settings; print the lines (or the JSON object); 0 when ready, else 1."""
    check_doctor(cfg)
    start = time.perf_counter()
    in_use = backend_in_use()
    running = start_backends(tuple(dict.fromkeys((*cfg.renderers, in_use))), cfg.timeout)
    out = _Printer(quiet=cfg.json)
    out.add(timed("python", python_check))
    out.add(*timed_all("versions", pin_checks))
    out.add(timed("torch", lambda: torch_check(cfg)))
    out.add(timed("libero", lambda: libero_check(cfg)))
    out.add(*timed_all("assets", lambda: assets_checks(cfg)))
    dims: list[tuple[int, int] | None] = [None]

    def policy() -> Check:
        check, dims[0] = policy_check(cfg)
        return check

    out.add(timed("policy", policy))
    out.add(timed("disk", lambda: disk_check(cfg, dims[0])))
    out.add(*renderer_checks({b: f.result() for b, f in running.items()}, in_use))
    out.add(timed("chromium", chromium_check))
    out.add(*(timed(tool[0], functools.partial(tool_check, *tool)) for tool in TOOLS))
    seconds = time.perf_counter() - start
    if cfg.json:
        print(json.dumps(to_json(out.checks, seconds), indent=2))
    else:
        print(closing_line(out.checks, seconds))
    return 0 if ready(out.checks) else 1
