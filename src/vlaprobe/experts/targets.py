"""Where a skill puts an object: onto or into a scene object (a plate, a bowl, a basket) or a BDDL region site
(a stove's cook region, a cabinet's top, a drawer, a placement region of the table)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.world import WorldState


@dataclass(frozen=True)
class Target:
    """A place target: row ``index`` of ``scene.tabletop`` (an object; ``site`` is -1), the MuJoCo site
    ``site`` of a region (``index`` is -1) with its world half extents ``half`` (LIBERO's ``in_box`` rule), or a
    fixed world point ``at`` (a spot of the table, ``half`` around it; ``index`` and ``site`` are -1)."""

    name: str
    index: int = -1
    site: int = -1
    half: tuple[float, float, float] = (0.0, 0.0, 0.0)
    at: tuple[float, float, float] | None = None

    @property
    def region(self) -> bool:
        """A place (a region or a point), not an object."""
        return self.site >= 0 or self.at is not None

    def point(self, state: WorldState, data: Any) -> np.ndarray:
        """The reference point: the object's body origin (as the world state has it), the site's centre or
        the fixed point."""
        if self.at is not None:
            return np.array(self.at)
        return data.site_xpos[self.site].copy() if self.site >= 0 else state.pos[self.index]


def find_target(env: Any, name: str) -> Target:
    """The :class:`Target` called ``name`` in a built :class:`~vlaprobe.envs.libero.LiberoTaskEnv`: a scene
    object or any BDDL region site (the workspace's placement regions included)."""
    if name in env.scene.tabletop:
        return Target(name, index=env.scene.tabletop.index(name))
    e = env.sim_env
    if name not in e.object_sites_dict:
        raise VlaprobeError(f"the scripted expert cannot find {name!r}: neither an object nor a region")
    model = e.sim.model
    site = int(model.site_name2id(name))
    rot = np.asarray(e.sim.data.site_xmat[site]).reshape(3, 3)
    half = np.abs(rot @ np.asarray(e.object_sites_dict[name].size, dtype=np.float64))
    return Target(name, site=site, half=(float(half[0]), float(half[1]), float(half[2])))
