"""The LIBERO checks: the package imports and reads its init states, and each suite's assets folder.

The assets are checked with the same per-suite check a run makes before building a scene
(:func:`vlaprobe.envs.assets.check_assets`); the run's suite must be complete, the other suites only warn. The
folder is also searched for generated stand-ins (:data:`STAND_INS`): files that replace LIBERO originals which
were not obtainable offline. They carry no mass, so physics, object states and atoms are LIBERO's, but the
images differ: a model trained on LIBERO's original images (OpenVLA's LIBERO fine-tunes) sees other pixels.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from pathlib import Path

from vlaprobe.configs.doctor import DoctorConfig
from vlaprobe.configs.env import SUITES, SuiteName
from vlaprobe.doctor.report import Check, timed
from vlaprobe.envs.assets import ASSETS_ENV, AssetFiles, check_assets, referenced_files
from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.openvla.embedded import MODEL_NAMES

STAND_INS: dict[str, str] = {
    "stable_scanned_objects/akita_black_bowl/visual/akita_black_bowl_vis.msh": "ef4c2b3c8084f61344a4cc82feee25d45cb3c3ccc3ad7fba31fe8945d0f89375",
    "stable_scanned_objects/akita_black_bowl/texture.png": "bfcb24ecc1ac6e640c95e3aac4fb3600e019ee6f3c45000e37e79e8be45f9a2a",
    "stable_scanned_objects/plate/texture.png": "a02577c621c344ec0da459c8659b975065678f5235f4bcf72095de98f4680639",
    "stable_scanned_objects/basket/visual/basket_vis.msh": "a8b9d5bb8a5f28ff8ce32f8324cab8ba789ddfbd06d73524bf6f22f0241d94c6",
    "stable_scanned_objects/basket/texture.png": "8599750f0f123f79f7e114a64ce74906211e20568a5b85a6c99b753d7ba3a2a0",
    "stable_scanned_objects/white_bowl/texture.png": "a2f57f8635cc4a4a152b5c637d850184dd803fa142cd0bf95eb2bf4608bc8c44",
    "turbosquid_objects/porcelain_mug/porcelain_mug_texture.png": "061d57cd082f92021d88959b2af8c83f7fdf7e4eeb2e7223419d03198116e17f",
    "turbosquid_objects/red_coffee_mug/red_coffee_mug_texture.png": "f40f9948791e089ae5c6c8e3bbbd67ae6f00ae59374334bcb3f50cf5061cceac",
    "turbosquid_objects/white_yellow_mug/white_yellow_mug_texture.png": "1de626e4b70e1005b03ef134c9f4b4dc52b95860b2b7de2b5506bb3d01255299",
    "turbosquid_objects/desk_caddy/desk_caddy_texture.png": "98e9f231dcb63b7224e647bb5001e6ad17da0e2e4092a8888e9f106870c12f2e",
    "turbosquid_objects/wooden_tray/crate_mat_BaseColor.png": "1eb48e1f95c63c9ee957d75d776fd49e10f953fdd4be4f261e16014c25b4b62b",
    "scenes/kitchen_background/visual/kitchen_background_vis.msh": "a27f77398ed3fc17145d02f9059dcb08a0cb91dca3e77edc29b5e6dc3cda4481",
    "scenes/kitchen_background_stove/visual/kitchen_background_stove_vis.msh": "9f0720d1f6ab9ac0199921a3518c93520eb0f6bee9dcb22c471ce6b926981aa8",
    "scenes/living_room/visual/living_room_vis.msh": "51264f0f66fbdd53f806fb83997c49abf907efc2ba0d9fab1fe055701d1ae7b8",
    "scenes/floor_lamp/visual/floor_lamp_vis.msh": "05718c8af847c0eb65b18486d42dd27ab10420e0e366eccea5b4140236c0e59c",
    "scenes/wall_decoration/wall_decoration_texture.png": "64c8173018884ed5ee4a13a93aaa69b282eda686805b9a136237523411a3240c",
}  # fmt: skip
"""SHA-256 of the 16 generated stand-ins of the offline assets copy (``../shared/libero_assets``, whose README
lists them), by path in the assets folder: a file with this path and content is a stand-in."""


def libero_check(cfg: DoctorConfig) -> Check:
    """LIBERO imports (its config written as a run writes it) and loads a task's init states (``torch.load``:
    the step that breaks when torch's loading defaults change)."""
    from vlaprobe.envs.libero import num_init_states, suite_tasks

    tasks = suite_tasks(cfg.env.suite)
    inits = num_init_states(cfg.env.suite, tasks[0][0])
    summary = f"imports; {cfg.env.suite}: {len(tasks)} tasks, {inits} init states of task {tasks[0][0]} load"
    return Check("libero", "ok", summary, figures={"tasks": len(tasks), "init_states": inits})


def assets_folder(cfg: DoctorConfig) -> tuple[Path | None, str]:
    """The folder a run would take its assets from, and where that choice came from (None: none here; LIBERO
    would download them on first use). Nothing is checked or downloaded here."""
    if cfg.env.assets is not None:
        return Path(cfg.env.assets).expanduser().resolve(), "--env.assets"
    if os.environ.get(ASSETS_ENV, "").strip():
        return Path(os.environ[ASSETS_ENV]).expanduser().resolve(), ASSETS_ENV
    spec = importlib.util.find_spec("libero")
    if spec is not None and spec.submodule_search_locations:
        own = Path(next(iter(spec.submodule_search_locations))) / "libero" / "assets"
        if own.is_dir():
            return own.resolve(), "the libero package"
    return None, ""


def suite_files(folder: Path, files: AssetFiles) -> list[Path]:
    """Every file a suite loads from ``folder``: its XML files and what they reference, each once."""
    found: dict[Path, None] = {}
    for rel in files.xml:
        found[folder / rel] = None
        found.update(dict.fromkeys(referenced_files(folder / rel, files.styled.get(rel, {}))))
    return list(found)


def stand_ins(folder: Path, files: list[Path]) -> list[str]:
    """The files among ``files`` that are generated stand-ins (paths relative to ``folder``)."""
    out = []
    for path in files:
        rel = os.path.relpath(path, folder)
        if (
            rel in STAND_INS
            and path.is_file()
            and hashlib.sha256(path.read_bytes()).hexdigest() == STAND_INS[rel]
        ):
            out.append(rel)
    return out


def suite_check(cfg: DoctorConfig, folder: Path, source: str, suite: SuiteName) -> Check:
    """One suite's files in ``folder``: complete and whole (a failure for the run's suite, else a warning), and
    how many are stand-ins."""
    from vlaprobe.envs.suite_assets import asset_files

    name, required = f"assets.{suite}", suite == cfg.env.suite
    try:
        files = asset_files(suite)
        check_assets(folder, files, suite)
    except VlaprobeError as exc:
        message, _, fix = str(exc).partition("; ")
        return Check(name, "fail" if required else "warn", message, fix)
    paths = suite_files(folder, files)
    fake = stand_ins(folder, paths)
    figures = {"folder": str(folder), "source": source, "files": len(paths), "stand_ins": fake}
    summary = f"{len(paths)} files complete in {folder} ({source})"
    if not fake:
        return Check(name, "ok", summary, figures=figures)
    summary += f"; {len(fake)} are generated stand-ins ({', '.join(str(Path(*Path(f).parts[1:])) for f in fake[:3])}{', ...' * (len(fake) > 3)}): rendered images differ from LIBERO's, physics and atoms do not"
    if required and cfg.policy.model not in MODEL_NAMES:
        fix = (
            "a checkpoint trained on LIBERO's images (OpenVLA's fine-tunes) should run on the original assets"
        )
        return Check(
            name, "warn", summary, f"{fix}: point {ASSETS_ENV} at LIBERO's own copy", figures=figures
        )
    return Check(name, "ok", summary, figures=figures)


def assets_checks(cfg: DoctorConfig) -> list[Check]:
    """The run's suite first, then every other suite."""
    folder, source = assets_folder(cfg)
    if folder is None or not folder.is_dir():
        where = (
            f"{folder} ({source}) is not a folder"
            if folder is not None
            else "no assets folder is set or installed"
        )
        fix = f"set {ASSETS_ENV} (or --env.assets) to a copy of LIBERO's assets; with internet access LIBERO downloads them on first use"
        return [Check(f"assets.{cfg.env.suite}", "fail", where, fix)]
    suites = [cfg.env.suite, *(s for s in SUITES if s != cfg.env.suite)]
    return [timed(f"assets.{s}", lambda s=s: suite_check(cfg, folder, source, s)) for s in suites]  # type: ignore[misc]
