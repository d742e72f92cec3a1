"""One cognition step (beliefs, all shipped rules in clingo, subgoals) for LIBERO-spatial's 236 atoms.

Target: median <= 1 ms per step. The input is probe-like: a consistent synthetic episode (objects drifting, the
bowl grasped, carried and placed) with 1 to 12 atoms wrong at every step (12: the most flips per step the live
integration notes measured), debouncing off, so every step changes beliefs and runs the solver. Also measured: the same with the default debounce, the step without the two
past-time rules (their cost), and grounding once per task. CPU time per step (process time) is printed beside
wall time: on a shared machine it is the figure that does not count other processes. No simulator; prints one
JSON line at the end.

    python bench/cognition_step.py
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from quick import size
from vlaprobe.cognition import Cognition, CognitionConfig, shipped_rules
from vlaprobe.configs.monitor import DEFAULT_DEBOUNCE
from vlaprobe.envs.spatial_scene import SPATIAL_GOAL, SPATIAL_SCENE
from vlaprobe.symbols import Vocabulary, build_vocabulary

STEPS, WARMUP, MAX_FLIPS = size(2000, 20), size(100, 2), 12
SCENE = SPATIAL_SCENE
GOAL = SPATIAL_GOAL


def truth(vocab: Vocabulary, seed: int = 0) -> np.ndarray:
    """A consistent episode (bool rows over all atoms): objects drift, the bowl is grasped, carried, placed."""
    rng = np.random.default_rng(seed)
    objects = SCENE.tabletop
    atoms = vocab.object_atoms + vocab.action_atoms
    index = {a: i for i, a in enumerate(atoms)}
    pos = rng.random((len(objects), 2))
    rows = np.zeros((STEPS + WARMUP, len(atoms)), dtype=bool)
    for t in range(len(rows)):
        pos += rng.normal(0, 0.003, pos.shape)
        phase = (t // 60) % 3  # approach, carry, placed
        true = [f"on-table({o})" for o in objects if not (o == GOAL.pick and phase > 0)]
        for i, a in enumerate(objects):
            for j, b in enumerate(objects):
                if i != j and pos[i, 0] < pos[j, 0] - 0.01:
                    true += [f"left-of({a},{b})", f"right-of({b},{a})"]
                if i != j and pos[i, 1] < pos[j, 1] - 0.01:
                    true += [f"behind({a},{b})", f"in-front-of({b},{a})"]
        true += [
            [f"should-move-towards({GOAL.pick})"],
            [f"grasped({GOAL.pick})", f"should-move-towards({GOAL.place})"],
            [f"on({GOAL.pick},{GOAL.place})"],
        ][phase]
        rows[t, [index[a] for a in true]] = True
    return rows


def stream(vocab: Vocabulary, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Probe-like predictions: the consistent episode with 1..MAX_FLIPS random atoms wrong at each step."""
    rng = np.random.default_rng(seed)
    n_obj = len(vocab.object_atoms)
    out = []
    for row in truth(vocab, seed):
        x = row.copy()
        wrong = rng.choice(x.size, size=rng.integers(1, MAX_FLIPS + 1), replace=False)
        x[wrong] = ~x[wrong]
        out.append((x[:n_obj], x[n_obj:]))
    return out


def time_steps(
    cog: Cognition, rows: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray, int]:
    """Wall and CPU milliseconds of each step after the warm-up, and the violations seen."""
    cog.reset()
    wall, cpu, violations = [], [], 0
    for i, (obj, act) in enumerate(rows):
        w, c = time.perf_counter(), time.process_time()
        step = cog.step(obj, act)
        if i >= WARMUP:
            wall.append(time.perf_counter() - w)
            cpu.append(time.process_time() - c)
            violations += len(step.violations)
    return np.array(wall) * 1e3, np.array(cpu) * 1e3, violations


def main() -> None:
    vocab = build_vocabulary(SCENE)
    atoms = (vocab.object_atoms, vocab.action_atoms)
    rows = stream(vocab)
    start = time.perf_counter()
    cog = Cognition(*atoms, GOAL, CognitionConfig(debounce=1))
    ground_ms = (time.perf_counter() - start) * 1e3
    every, cpu, violations = time_steps(cog, rows)
    debounced, _, _ = time_steps(Cognition(*atoms, GOAL, CognitionConfig(debounce=DEFAULT_DEBOUNCE)), rows)
    text = shipped_rules("lp").read_text()
    with tempfile.TemporaryDirectory() as tmp:  # the shipped rules without the two past-time ones
        static = Path(tmp) / "static.lp"
        static.write_text(text.split("% --- over the history")[0])
        cfg = CognitionConfig(debounce=1, shipped_rules=False, rules=(static,))
        no_temporal, cpu_no_temporal, _ = time_steps(Cognition(*atoms, GOAL, cfg), rows)
    figures = {
        "atoms": len(vocab.object_atoms) + len(vocab.action_atoms),
        "rules": len(cog.rules.messages),
        "steps": STEPS,
        "max_flips_per_step": MAX_FLIPS,
        "violations_per_step": round(violations / STEPS, 2),
        "ms_per_step": round(float(np.median(every)), 4),
        "p95_ms": round(float(np.percentile(every, 95)), 4),
        "cpu_ms_per_step": round(float(np.median(cpu)), 4),
        "ms_per_step_default_debounce": round(float(np.median(debounced)), 4),
        "ms_per_step_without_past_time_rules": round(float(np.median(no_temporal)), 4),
        "cpu_ms_per_step_without_past_time_rules": round(float(np.median(cpu_no_temporal)), 4),
        "ground_ms": round(ground_ms, 1),
        "target_ms": 1.0,
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
