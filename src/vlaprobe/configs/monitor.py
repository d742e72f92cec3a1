"""Configuration of the cognition (belief store, rules, subgoals) and of `vlaprobe cognition` (the offline cognition evaluation)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

DEFAULT_DEBOUNCE = 3
"""Steps a belief change must hold before it counts; chosen from measurements in docs/cognition.md."""


@dataclass(frozen=True)
class RuleBudget:
    """Bounds on users' rules files (the shipped rules are not bounded): a rule that grounds without end
    (``n(X+1) :- n(X).``) or a search that never finishes stops with one line naming the rule."""

    ground_seconds: float = 10.0
    """Most seconds grounding may take (it runs first in a child process, killed at this limit)."""
    ground_atoms: int = 1_000_000
    """Most ground atoms the program may have (the shipped rules over 236 atoms: about 2,000)."""
    ground_memory_mb: int = 2048
    """Most memory (address space, MB) the grounding's child process may use."""
    solve_seconds: float = 2.0
    """Most seconds one step's solve may take (the shipped rules: under 1 ms)."""


@dataclass(frozen=True)
class CognitionConfig:
    """How per-step truth values become beliefs, violations and subgoal states."""

    rules: tuple[Path, ...] = ()
    """Extra rules files (clingo ASP, see docs/cognition.md), evaluated with the shipped ones."""
    shipped_rules: bool = True
    """Evaluate the shipped rules (src/vlaprobe/cognition/rules/consistency.lp)."""
    debounce: int = DEFAULT_DEBOUNCE
    """A belief change counts once the new value has held this many consecutive steps (1: every change).
    Rules and subgoals see the debounced beliefs, so a violation from a shorter flicker never appears."""
    recent_steps: int = 10
    """Window of the rules' past-time operator recent(B): B held at one of the last this-many steps."""
    stall_steps: int = 150
    """Raise a "stalled" event when no subgoal has been done for this many steps before the goal (the scripted
    expert needs up to 116 steps from the start to its grasp)."""
    regression_steps: int = 8
    """A subgoal counts as undone once the beliefs have stopped supporting it for this many consecutive steps
    (the scripted expert lets go 2-3 steps before the object rests on its place)."""
    budget: RuleBudget = field(default_factory=RuleBudget)
    """Time, size and memory bounds on grounding and solving users' rules files."""


@dataclass
class MonitorConfig:
    """`vlaprobe cognition`: run the cognition over stored episodes on ground truth and on probe predictions."""

    store: Path = Path("runs/default/activations")
    """Activation store (the --out folder of `vlaprobe collect`)."""
    probes: Path = Path("runs/default/probes")
    """Probe folder written by `vlaprobe train` (probes.json, probes.safetensors, evaluation.json)."""
    rules: tuple[Path, ...] = ()
    """Extra rules files (clingo ASP) added to the shipped ones."""
    out: Path | None = None
    """Folder for monitor.json; default: the probe folder."""
    json: bool = False
    """Print the figures as one JSON object on stdout."""
    all_episodes: bool = False
    """Every stored episode instead of the probes' held-out test episodes (checks the rules on truth)."""
    extra_stores: tuple[Path, ...] = ()
    """More stores observed by the same model whose episodes (all of them, never trained on) join the figures:
    e.g. policy-driven episodes that fail, so goal detection is measured on failures too."""
    debounce: int = DEFAULT_DEBOUNCE
    """Steps a belief change must hold before it counts (the same for truth and predictions)."""
    recent_steps: int = 10
    """Window of the rules' past-time operator recent(B), in steps."""
    stall_steps: int = 150
    """Steps without a new subgoal done before a "stalled" event."""
    regression_steps: int = 8
    """Consecutive steps the beliefs must stop supporting a done subgoal before it counts as undone."""
    budget: RuleBudget = field(default_factory=RuleBudget)
    """Time, size and memory bounds on grounding and solving the --rules files."""

    def cognition(self) -> CognitionConfig:
        """The cognition settings these options describe."""
        return CognitionConfig(
            rules=tuple(self.rules),
            debounce=self.debounce,
            recent_steps=self.recent_steps,
            stall_steps=self.stall_steps,
            regression_steps=self.regression_steps,
            budget=self.budget,
        )
