"""scripts/takeover_comparison.py on a round collected on the fake simulator through the real worker and store:
the counts, the rates and the takeovers' ends are read as written."""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path
from types import ModuleType

from tests.cognition.test_alarm import _config, _takeovers
from tests.collection.fakes import make_fake_worker

from vlaprobe.cognition.alarm import CognitionSupervisor
from vlaprobe.collection.collect import collect
from vlaprobe.collection.store import ActivationStore

SCRIPT = Path(__file__).parents[2] / "scripts" / "takeover_comparison.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("takeover_comparison", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_comparison_counts_each_condition_of_a_round(tmp_path: Path) -> None:
    cog = functools.partial(make_fake_worker, make_supervisor=CognitionSupervisor)
    r = tmp_path / "r40"
    collect(_config(r / "alarm", takeover="alarm", takeover_stall=4, takeover_steps=8), cog)
    collect(_config(r / "random", takeover="random", takeover_steps=8, takeover_match=r / "alarm"), cog)
    collect(_config(r / "none"), cog)
    out = _script().compare([r, tmp_path / "r41"])  # a round not there yet adds nothing
    for c in ("none", "alarm", "random"):
        s = ActivationStore.open(r / c)
        eps = s.episodes()
        assert out[c]["episodes"] == len(eps) and out[c]["successes"] == sum(e.success for e in eps)
        taken = [] if c == "none" else [i for t in _takeovers(r / c).values() for i in t.items]
        assert out[c]["takeovers_per_episode"] == len(taken) / len(eps)
        assert sum(out[c]["ended"].values()) == len(taken)
        if taken:
            assert out[c]["actions_per_takeover"] == sum(i.steps for i in taken) / len(taken)
    assert out["none"]["ended"] == {} and out["alarm"]["takeovers_per_episode"] > 0
