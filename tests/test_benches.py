"""Every bench runs in quick mode (``VLAPROBE_BENCH_QUICK=1``) and ends with its JSON line: a change of defaults
(a new default observer, a renamed setting) cannot break one silently."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHES = sorted(p.stem for p in (ROOT / "bench").glob("*.py") if p.stem != "quick")
LIBERO = {
    "collect_throughput", "diverse_data", "expert_success", "init_variation", "label_speed", "live",
    "placement_checks",
}  # fmt: skip
"""Benches that build the real LIBERO simulator."""
KEYS = {
    "c_search": "ratio", "capture_overhead": "ratio", "cognition_step": "ms_per_step", "collect_throughput": "steps_per_s",
    "diverse_data": "wall_s", "expert_success": "success_rate", "finetune": "samples_per_s",
    "gpu": "parameters",
    "init_variation": "varying", "label_speed": "label_ms_per_state", "lbfgs_threads": "speedup", "live": "rate_ratio",
    "placement_checks": "libero_fixed_inits", "probe_training": "speedup", "tiny_forward": "ms_per_step",
    "takeover_alarm": "alarm_ms_median",
    "web_ui": "steps",
}  # fmt: skip
"""A key each bench's final JSON line (or each of its rows) must hold."""


def test_every_bench_is_listed() -> None:
    assert set(BENCHES) == set(KEYS)


@pytest.mark.serial
@pytest.mark.timeout(900)
@pytest.mark.parametrize(
    "bench", [pytest.param(b, marks=[pytest.mark.libero] if b in LIBERO else []) for b in BENCHES]
)
def test_bench_runs_in_quick_mode(bench: str, tmp_path: Path) -> None:
    if bench == "web_ui" and not shutil.which("chromium"):
        pytest.skip("needs /usr/bin/chromium (docs/setup.md)")
    env = {**os.environ, "VLAPROBE_BENCH_QUICK": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), env.get("PYTHONPATH", "")])
    env["VLAPROBE_FIXED_STORE"] = str(tmp_path / "none")  # diverse_data: without the default run's store
    done = subprocess.run(
        [sys.executable, str(ROOT / "bench" / f"{bench}.py")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=840,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    last = json.loads(done.stdout.strip().splitlines()[-1])
    rows = last if isinstance(last, list) else [last]  # init_variation: one row per task
    assert rows and all(isinstance(r, dict) and KEYS[bench] in r for r in rows), last
