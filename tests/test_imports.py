"""Importing vlaprobe never imports MuJoCo: MuJoCo picks its OpenGL backend once, on import, from ``MUJOCO_GL``,
which ``vlaprobe.envs.setup`` sets before LIBERO loads. A module importing it first (e.g. when pytest collects a
test file) leaves the process with GLFW, which cannot render without a display (a CI failure of 2026-12-06:
segmentation renders of garbage in tests/envs/test_libero.py after tests/experts/test_arm.py was collected)."""

from __future__ import annotations

import os
import subprocess
import sys

PROBE = """
import importlib, pkgutil, sys
import vlaprobe
for m in pkgutil.walk_packages(vlaprobe.__path__, "vlaprobe."):
    importlib.import_module(m.name)
    assert "mujoco" not in sys.modules, m.name
print("ok")
"""


def test_no_vlaprobe_module_imports_mujoco_on_import() -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]
