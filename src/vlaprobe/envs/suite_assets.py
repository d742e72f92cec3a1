"""The asset files a suite loads, read from its BDDL files and LIBERO's source (no simulator, no assets).

Per task: the problem class's scene XML (with the floor and wall textures its style swaps in) and the XML of every
object and fixture category but the workspace. :func:`suite_asset_files` lists them once each, task by task, so
:func:`~vlaprobe.envs.assets.check_assets` names the first missing one before anything is built.
"""

from __future__ import annotations

from functools import lru_cache

from vlaprobe.configs.env import SuiteName
from vlaprobe.envs.assets import SPATIAL_ASSETS, AssetFiles
from vlaprobe.envs.bddl_scene import task_bddl
from vlaprobe.envs.libero_source import object_facts, problem_facts, texture_styles
from vlaprobe.errors import VlaprobeError


@lru_cache(maxsize=8)
def suite_asset_files(suite: SuiteName) -> AssetFiles:
    """Every XML file ``suite``'s tasks load, scene XMLs first, each once, and their styled textures."""
    from vlaprobe.envs.libero import suite_tasks

    scenes: dict[str, dict[str, str]] = {}
    objects: dict[str, None] = {}
    styles, facts = texture_styles(), object_facts()
    for task, _ in suite_tasks(suite):
        problem = task_bddl(suite, task)
        pf = problem_facts()[problem.problem_class]
        scenes[pf.scene_xml] = {
            "texplane": styles["floor"][pf.floor_style],
            "tex-wall": styles["wall"][pf.wall_style],
        }
        for named in problem.fixtures + problem.objects:
            if named.category == pf.workspace:
                continue
            if named.category not in facts:
                raise VlaprobeError(
                    f"{suite} task {task}: LIBERO object category {named.category!r} is not registered in the "
                    "installed libero package; reinstall LIBERO (`make setup`)"
                )
            objects[facts[named.category].xml] = None
    return AssetFiles(xml=tuple(scenes) + tuple(objects), styled=scenes)


def asset_files(suite: SuiteName) -> AssetFiles:
    """LIBERO-spatial's constant list (no libero source needed), any other suite's from its BDDL files."""
    return SPATIAL_ASSETS if suite == "libero_spatial" else suite_asset_files(suite)
