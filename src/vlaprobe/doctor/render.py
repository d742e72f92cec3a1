"""The renderer checks: each ``MUJOCO_GL`` backend tried in its own process, timed, and the images compared.

The backends run in parallel threads (one subprocess each, ended after ``--timeout`` seconds) while the
doctor's other checks run. The backend a run would use (``$MUJOCO_GL``, else OSMesa when installed, else EGL:
``vlaprobe.envs.setup``) must render; another that fails only warns. Two backends can draw the same scene
differently (a GPU's EGL against Mesa's software OSMesa): a model sees other pixels than those it was trained on.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import vlaprobe
from vlaprobe.doctor.report import Check
from vlaprobe.files import JsonObject

DIFFERENT = 8
"""A pixel "differs" between two backends when a channel differs by more than this (of 255)."""


@dataclass(frozen=True)
class BackendRun:
    """One backend's attempt."""

    backend: str
    seconds: float
    """Wall time of its process (start-up, MuJoCo's import, the renders)."""
    figures: JsonObject
    """The child's report (``first_seconds``, ``render_ms``, ``gl_renderer``, ``mujoco``); empty on failure."""
    image: np.ndarray | None
    error: str
    """Why it did not render ("" when it did)."""


def child_env(backend: str) -> dict[str, str]:
    """This process's environment with ``MUJOCO_GL`` (and PyOpenGL's platform) set to ``backend``, and the
    vlaprobe being run importable."""
    env = dict(os.environ, MUJOCO_GL=backend)
    if backend in ("osmesa", "egl"):
        env["PYOPENGL_PLATFORM"] = backend
    else:
        env.pop("PYOPENGL_PLATFORM", None)
    src = str(Path(vlaprobe.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH", "")) if p)
    return env


def run_backend(backend: str, timeout: float) -> BackendRun:
    """Render the child's scene with ``backend`` in a fresh process (ended after ``timeout`` seconds)."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="vlaprobe-doctor-") as tmp:
        out = Path(tmp) / "image.npy"
        command = [sys.executable, "-m", "vlaprobe.doctor.render_child", str(out)]
        try:
            done = subprocess.run(
                command, env=child_env(backend), capture_output=True, text=True, timeout=timeout
            )
        except subprocess.TimeoutExpired:
            error = f"no image within {timeout:g} s (a hanging driver?); its process was ended"
            return BackendRun(backend, time.perf_counter() - start, {}, None, error)
        except OSError as exc:
            return BackendRun(backend, 0.0, {}, None, f"cannot start {sys.executable}: {exc.strerror or exc}")
        seconds = time.perf_counter() - start
        lines = done.stdout.strip().splitlines()
        try:
            said = json.loads(lines[-1]) if lines else {}
        except json.JSONDecodeError:
            said = {}
        said = said if isinstance(said, dict) else {}
        if done.returncode == 0 and "error" not in said and out.is_file():
            return BackendRun(backend, seconds, said, np.load(out), "")
    error = (
        said.get("error") or _last_line(done.stderr) or f"its process exited with status {done.returncode}"
    )
    return BackendRun(backend, seconds, {}, None, str(error))


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if lines else ""


def start_backends(backends: tuple[str, ...], timeout: float) -> dict[str, Future[BackendRun]]:
    """Start every backend's process now (threads); the results are collected by :func:`renderer_checks`."""
    pool = ThreadPoolExecutor(max_workers=max(1, len(backends)), thread_name_prefix="doctor-render")
    futures = {b: pool.submit(run_backend, b, timeout) for b in backends}
    pool.shutdown(wait=False)
    return futures


def renderer_checks(runs: dict[str, BackendRun], in_use: str) -> list[Check]:
    """One line per backend (the one in use fails the doctor, another warns), then the images compared."""
    working = [b for b, r in runs.items() if r.image is not None]
    checks = []
    for backend, run in runs.items():
        name, mark = f"renderer.{backend}", " (what a run uses)" if backend == in_use else ""
        if run.image is not None:
            f = run.figures
            summary = (
                f"renders{mark}: {f['render_ms']:.0f} ms per {run.image.shape[1]}² frame, first after "
                f"{f['first_seconds']:.1f} s, {f['gl_renderer']}; process {run.seconds:.1f} s"
            )
            checks.append(Check(name, "ok", summary, seconds=round(run.seconds, 3), figures=f))
            continue
        others = [b for b in working if b != backend]
        instead = (
            f"or set MUJOCO_GL={others[0]} (it renders here)" if others else "or try MUJOCO_GL=egl on a GPU"
        )
        fix = f"{FIXES.get(backend, 'check the backend name')}, {instead}"
        summary = f"fails{mark}: {run.error}"
        checks.append(
            Check(name, "fail" if backend == in_use else "warn", summary, fix, round(run.seconds, 3))
        )
    checks.append(compare_check(runs, in_use))
    return checks


FIXES = {
    "osmesa": "apt install libosmesa6",
    "egl": "install the GPU driver's EGL (or Mesa's: apt install libegl1 libgl1-mesa-dri)",
    "glx": "GLX needs an X display (DISPLAY): use osmesa or egl on a headless machine",
}


def compare_check(runs: dict[str, BackendRun], in_use: str) -> Check:
    """The image of the backend in use against every other backend that rendered the same scene."""
    images = {b: r.image for b, r in runs.items() if r.image is not None}
    if in_use not in images or len(images) < 2:
        return Check(
            "renderer.compare",
            "skip",
            f"needs two rendering backends, one of them {in_use}; {len(images)} rendered",
        )
    parts, figures, differ = [], {}, False
    for backend, image in images.items():
        if backend == in_use:
            continue
        delta = np.abs(images[in_use].astype(np.int16) - image.astype(np.int16))
        share = float((delta.max(axis=-1) > DIFFERENT).mean())
        figures[backend] = {
            "mean_abs": float(delta.mean()),
            "max_abs": int(delta.max()),
            "share_differing": share,
        }
        differ |= bool(delta.max() > 0)
        parts.append(
            f"{in_use} vs {backend}: mean |Δ| {delta.mean():.2f}/255, max {delta.max()}, "
            f"{100 * share:.1f}% pixels differ by > {DIFFERENT}"
        )
    if differ:
        fix = f"a model sees the pixels of the backend it runs with: evaluate with the one it was trained with (MUJOCO_GL={in_use} now)"
        return Check("renderer.compare", "warn", "; ".join(parts), fix, figures=figures)
    return Check("renderer.compare", "ok", "; ".join(parts) + " (identical)", figures=figures)
