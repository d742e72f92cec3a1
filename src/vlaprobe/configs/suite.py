"""Configs of the suite commands ``vlaprobe tasks`` and ``vlaprobe atoms``."""

from __future__ import annotations

from dataclasses import dataclass, field

from vlaprobe.configs.env import EnvConfig


@dataclass
class TasksConfig:
    """List the suite's tasks."""

    env: EnvConfig = field(default_factory=EnvConfig)
    """Simulator settings (only the suite matters here)."""
    json: bool = False
    """Print a JSON list instead of a table."""


@dataclass
class AtomsConfig:
    """Print the symbolic atoms at a task's settled init state."""

    task: int | str = 0
    """Task index (0-9) or its exact instruction."""
    init: int = 0
    """Index of the benchmark's fixed init state (0-49)."""
    json: bool = False
    """Print {"task", "init", "instruction", "object": {atom: 0|1}, "action": {atom: 0|1}}."""
    all: bool = False
    """List every atom with its value instead of only the true ones (ignored with --json, which has all)."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Simulator settings."""
