"""Make LIBERO importable without prompts, find its assets, and pick an offscreen renderer.

Call :func:`prepare_libero` before the first ``import libero``. It is idempotent.

Traps it handles (measured, see ``../shared/LIBERO_NOTES.md``):
- ``import libero.libero`` calls ``input()`` when ``$LIBERO_CONFIG_PATH/config.yaml`` is missing, which hangs
  a CI job: we write that config ourselves into a folder we own.
- LIBERO ignores the config's ``assets`` key: ``get_assets_path()`` uses ``site-packages/libero/libero/assets``
  when it exists, else downloads from a model hub. We set LIBERO's module-level cache to our folder instead.
- A damaged assets folder (a missing texture, a cut mesh, a malformed XML) would end in a MuJoCo traceback inside
  robosuite: every file the suite loads is checked first (``vlaprobe.envs.assets``), an error is one line.
- robosuite forces EGL unless ``MUJOCO_GL`` is ``osmesa`` or ``glx``; on a machine without a GPU we choose
  OSMesa when its library is installed (``libosmesa6``), else Mesa's software EGL.
"""

from __future__ import annotations

import ctypes.util
import os
from pathlib import Path
from types import ModuleType

from vlaprobe.configs.env import SuiteName
from vlaprobe.envs.assets import ASSETS_ENV, check_assets
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import write_atomic

_prepared_assets: Path | None = None
_checked_assets: set[tuple[Path, str]] = set()


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


def _config_dir(root: Path) -> Path:
    """The config folder of the LIBERO installed at ``root``: one per install, because LIBERO re-reads the file
    at every path lookup, and two checkouts sharing one folder rewrote each other's paths under running
    episodes (a removed checkout's then ended them)."""
    import hashlib

    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "vlaprobe" / "libero" / hashlib.sha256(str(root.resolve()).encode()).hexdigest()[:16]


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
    cfg_dir = _config_dir(root)
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


def _checked(folder: Path, suite: SuiteName) -> Path:
    """``folder`` after :func:`~vlaprobe.envs.assets.check_assets` of ``suite``'s files (once per folder, suite
    and process)."""
    if (folder, suite) not in _checked_assets:
        from vlaprobe.envs.suite_assets import asset_files

        check_assets(folder, asset_files(suite), suite)
        _checked_assets.add((folder, suite))
    return folder


def resolve_assets(assets: str | Path | None, suite: SuiteName = "libero_spatial") -> Path | None:
    """The assets folder to use, checked for ``suite``'s files: the argument, else ``$VLAPROBE_LIBERO_ASSETS``, else
    None (LIBERO's own)."""
    if assets is not None:
        chosen, source = str(assets), "--env.assets"
    elif ASSETS_ENV in os.environ:
        chosen, source = os.environ[ASSETS_ENV], ASSETS_ENV
    else:
        return None
    if not chosen.strip():
        raise VlaprobeError(
            f"{source} is empty; set it to LIBERO's assets folder (or unset it to use the libero package's own)"
        )
    folder = Path(chosen).expanduser().resolve()
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.exists() else "not found"
        raise VlaprobeError(
            f"LIBERO assets folder {folder} {what}; set {ASSETS_ENV} (or --env.assets) to LIBERO's assets folder"
        )
    return _checked(folder, suite)


def _libero_own_assets(libero_root: ModuleType, suite: SuiteName) -> Path:
    """LIBERO's own assets: inside the libero package, else downloaded from the Hugging Face Hub (its chatter,
    on stdout and stderr, is kept out of the terminal: stdout must stay clean for --json output)."""
    import contextlib
    import io
    import sys

    local = Path(str(libero_root.__file__)).parent / "assets"
    if not local.is_dir():
        print(
            f"vlaprobe: no LIBERO assets in the libero package; downloading them ({ASSETS_ENV} names a local copy)",
            file=sys.stderr,
        )
    chatter = io.StringIO()
    with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
        found = Path(libero_root.get_assets_path())
    if not found.is_dir():
        raise VlaprobeError(
            f"LIBERO assets not found (the libero package has none and the download failed); "
            f"set {ASSETS_ENV} (or --env.assets) to a folder holding LIBERO's assets"
        )
    return _checked(found.resolve(), suite)


def prepare_libero(
    assets: str | Path | None = None, *, need_assets: bool = True, suite: SuiteName = "libero_spatial"
) -> Path | None:
    """Set up rendering, LIBERO's config and assets (checked for ``suite``'s files); returns the assets folder in
    use (None: not needed).

    ``need_assets=False`` (listing a suite's tasks) makes LIBERO importable without looking for assets.
    """
    global _prepared_assets
    _choose_gl_backend()
    _write_libero_config()
    if not need_assets:
        return None
    folder = resolve_assets(assets, suite)
    _quiet_import_robosuite()
    import libero.libero as libero_root  # safe now: the config exists

    if folder is not None:
        libero_root._assets_path_cache = str(folder)
    elif _prepared_assets is None:
        folder = _libero_own_assets(libero_root, suite)
    else:
        folder = _checked(_prepared_assets, suite)
    _prepared_assets = folder
    return folder
