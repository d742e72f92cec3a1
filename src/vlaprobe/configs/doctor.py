"""Config of ``vlaprobe doctor``: will this machine run ``vlaprobe run`` with these settings?"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal, get_args

import tyro

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.policy import PolicyConfig

GLBackend = Literal["osmesa", "egl", "glx"]
"""MuJoCo's offscreen OpenGL backends (``MUJOCO_GL``): OSMesa (software), EGL (a GPU's driver, or Mesa's
software EGL), GLX (an X display)."""
GL_BACKENDS: tuple[GLBackend, ...] = get_args(GLBackend)


@dataclass
class DoctorConfig:
    """Check and time what ``vlaprobe run`` needs on this machine, one line per check with its fix.

    Exit status 0: everything a run of these settings needs is there (optional things, such as a second
    renderer backend or the browser of the tests, only warn); 1: a check failed; 2: bad flags.
    """

    policy: Annotated[PolicyConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=PolicyConfig)
    """The model the run will load (--model tiny-libero|FOLDER, --device, --pooling ...): loaded, and one step
    timed with and without the hidden-state capture."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """The suite and assets folder the run will use (--suite, --env.assets). The other suites' assets are
    checked too, as warnings."""
    out: Path = Path("runs/default")
    """The run folder: the free disk is measured where it is, or would be, created."""
    episodes: int = 30
    """Episodes the run stores (tasks x --collect.episodes-per-task; the default run: 10 x 3): with the model's
    size and --env.max-steps they give the store's size, checked against the free disk."""
    control: bool = True
    """The run also stores a control observer's states of the same episodes (``--control-model``, on by
    default): room for a second store of the same size."""
    renderers: tuple[GLBackend, ...] = GL_BACKENDS
    """Renderer backends to try, each in a subprocess (one render timed; the images compared). The one a run
    would use must work; the others only warn."""
    timeout: float = 60.0
    """Seconds a renderer's subprocess may take before it is ended and reported as hanging."""
    json: bool = False
    """Print one JSON object (format "vlaprobe-doctor": "ready" and every check's status, summary, fix,
    seconds and figures) instead of the lines."""
