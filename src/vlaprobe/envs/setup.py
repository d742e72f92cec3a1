"""Make LIBERO importable without prompts, find its assets, and pick an offscreen renderer.

Call :func:`prepare_libero` before the first ``import libero``. It is idempotent.

Traps it handles (measured, see ``../shared/LIBERO_NOTES.md``):
- ``import libero.libero`` calls ``input()`` when ``$LIBERO_CONFIG_PATH/config.yaml`` is missing, which hangs
  a CI job: we write that config ourselves into a folder we own.
- LIBERO ignores the config's ``assets`` key: ``get_assets_path()`` uses ``site-packages/libero/libero/assets``
  when it exists, else downloads from a model hub. We set LIBERO's module-level cache to our folder instead.
- robosuite forces EGL unless ``MUJOCO_GL`` is ``osmesa`` or ``glx``; on a machine without a GPU we choose
  OSMesa when its library is installed (``libosmesa6``), else Mesa's software EGL.
"""

from __future__ import annotations

import ctypes.util
import os
from pathlib import Path

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import write_atomic

ASSETS_ENV = "VLAPROBE_LIBERO_ASSETS"

# Files LIBERO-spatial loads, relative to the assets folder. Checked up front so that a missing file is one
# clear line instead of a MuJoCo XML error deep inside robosuite.
SPATIAL_ASSET_FILES: tuple[str, ...] = (
    "scenes/libero_tabletop_base_style.xml",
    "articulated_objects/wooden_cabinet.xml",
    "articulated_objects/flat_stove.xml",
    "stable_scanned_objects/akita_black_bowl/akita_black_bowl.xml",
    "stable_scanned_objects/plate/plate.xml",
    "stable_hope_objects/cookies/cookies.xml",
    "stable_scanned_objects/glazed_rim_porcelain_ramekin/glazed_rim_porcelain_ramekin.xml",
)

_prepared_assets: Path | None = None


def _choose_gl_backend() -> None:
    """Pick an offscreen OpenGL backend unless the user already chose one."""
    if "MUJOCO_GL" in os.environ:
        if os.environ["MUJOCO_GL"] == "osmesa":
            os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
        return
    if ctypes.util.find_library("OSMesa"):
        os.environ["MUJOCO_GL"] = "osmesa"
        os.environ["PYOPENGL_PLATFORM"] = "osmesa"
    else:
        os.environ["MUJOCO_GL"] = "egl"
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def _config_dir() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "vlaprobe" / "libero"


def _write_libero_config() -> None:
    """Write LIBERO's config.yaml (pointing into the installed package) so its import never prompts."""
    if (
        "LIBERO_CONFIG_PATH" in os.environ
        and (Path(os.environ["LIBERO_CONFIG_PATH"]) / "config.yaml").is_file()
    ):
        return
    import importlib.util

    spec = importlib.util.find_spec("libero")
    if spec is None or not spec.submodule_search_locations:
        raise VlaprobeError("LIBERO is not installed; run `bash scripts/setup.sh` (or `make setup`) first")
    root = Path(next(iter(spec.submodule_search_locations))) / "libero"
    cfg_dir = _config_dir()
    cfg_dir.mkdir(parents=True, exist_ok=True)
    text = "".join(
        f"{key}: {value}\n"
        for key, value in {
            "benchmark_root": root,
            "bddl_files": root / "bddl_files",
            "init_states": root / "init_files",
            "datasets": root.parent / "datasets",
            "assets": root / "assets",
        }.items()
    )
    target = cfg_dir / "config.yaml"
    if not target.is_file() or target.read_text() != text:
        write_atomic(target, text)
    os.environ["LIBERO_CONFIG_PATH"] = str(cfg_dir)


def _quiet_import_robosuite() -> None:
    """Import robosuite with its start-up advice about a private macro file silenced.

    robosuite's logger writes to the stream that is ``sys.stderr`` when the logger is created, so creating it
    under a redirect keeps its console output (warnings about macros, not about our runs) out of the terminal.
    """
    import sys

    if "robosuite" in sys.modules:
        return
    import contextlib
    import io
    import logging

    with contextlib.redirect_stderr(io.StringIO()):
        import robosuite  # noqa: F401
    logging.getLogger("robosuite_logs").setLevel(logging.ERROR)


def resolve_assets(assets: str | Path | None) -> Path | None:
    """The assets folder to use: the argument, else ``$VLAPROBE_LIBERO_ASSETS``, else None (LIBERO's own)."""
    chosen = assets if assets is not None else os.environ.get(ASSETS_ENV) or None
    if chosen is None:
        return None
    folder = Path(chosen).expanduser().resolve()
    if not folder.is_dir():
        raise VlaprobeError(
            f"LIBERO assets folder not found: {folder}; set {ASSETS_ENV} (or --env.assets) to LIBERO's assets folder"
        )
    for rel in SPATIAL_ASSET_FILES:
        if not (folder / rel).is_file():
            raise VlaprobeError(
                f"LIBERO assets folder {folder} is incomplete: missing {rel}; "
                f"point {ASSETS_ENV} (or --env.assets) at a complete copy of LIBERO's assets folder"
            )
    return folder


def prepare_libero(assets: str | Path | None = None) -> Path | None:
    """Set up rendering, LIBERO's config and assets; returns the assets folder in use (None: LIBERO's own)."""
    global _prepared_assets
    _choose_gl_backend()
    _write_libero_config()
    folder = resolve_assets(assets)
    _quiet_import_robosuite()
    import libero.libero as libero_root  # safe now: the config exists

    if folder is not None:
        libero_root._assets_path_cache = str(folder)
    elif _prepared_assets is None:
        # LIBERO's own lookup: its package folder, else a download from a model hub. It reports progress
        # on stdout, which must stay clean for --json output.
        import contextlib
        import sys

        with contextlib.redirect_stdout(sys.stderr):
            found = Path(libero_root.get_assets_path())
        missing = [rel for rel in SPATIAL_ASSET_FILES if not (found / rel).is_file()]
        if missing:
            raise VlaprobeError(
                f"LIBERO assets not found (no {found / missing[0]}) and LIBERO could not download them; "
                f"set {ASSETS_ENV} (or --env.assets) to a folder holding LIBERO's assets"
            )
        folder = found
    _prepared_assets = folder
    return folder
