"""The one step loop both collection and the live server run, and the drivers that choose the actions.

``run_episode(env, policy, driver, init=..., max_steps=...)`` yields a :class:`StepRecord` per observation;
collection buffers them into the store, a live server streams them (and pauses, stops or perturbs the
episode through an :class:`EpisodeControl`). :class:`EpisodeRunner` (with its :class:`EnvCache`) is how both
run an episode: seeding, the driver, the loop; :func:`paced` replays stored records under the same control;
:class:`DeferredObserver` lets the model observe an expert-driven episode after it ran, in batches.
"""

from vlaprobe.configs.collect import DriverName
from vlaprobe.rollout.deferred import DeferredObserver
from vlaprobe.rollout.drivers import (
    DaggerDriver,
    Driver,
    ExpertDriver,
    PolicyDriver,
    make_driver,
)
from vlaprobe.rollout.loop import EpisodeControl, StepRecord, StepTimings, SuccessTracker, run_episode
from vlaprobe.rollout.runner import EnvCache, EpisodeRunner, paced, seed_everything

__all__ = [
    "DaggerDriver",
    "DeferredObserver",
    "Driver",
    "DriverName",
    "EnvCache",
    "EpisodeControl",
    "EpisodeRunner",
    "ExpertDriver",
    "PolicyDriver",
    "StepRecord",
    "StepTimings",
    "SuccessTracker",
    "make_driver",
    "paced",
    "run_episode",
    "seed_everything",
]
