"""The one step loop both collection and the live server run, and the drivers that choose the actions.

``run_episode(env, policy, driver, init=..., max_steps=...)`` yields a :class:`StepRecord` per observation;
collection buffers them into the store, a live server streams them (and pauses, stops or perturbs the
episode through an :class:`EpisodeControl`).
"""

from vlaprobe.rollout.drivers import Driver, DriverName, ExpertDriver, PolicyDriver, make_driver
from vlaprobe.rollout.loop import EpisodeControl, StepRecord, StepTimings, run_episode

__all__ = [
    "Driver",
    "DriverName",
    "EpisodeControl",
    "ExpertDriver",
    "PolicyDriver",
    "StepRecord",
    "StepTimings",
    "make_driver",
    "run_episode",
]
