"""Collection throughput: steps/s of expert + tiny model + rendering + labelling + writing, and the share of
step time spent labelling and writing (target <= 5%).

Runs ``vlaprobe collect`` in this process (one worker, the real LIBERO scene at the default 256x256 render,
the embedded tiny OpenVLA observing, the scripted expert acting) into a temporary store, then reads the
store back for its size. Labelling = world-state snapshots + detectors, timed inside the step loop; writing
= staging, fsync and publishing, timed in the parent. Both are measured in the same run as the step time
they are compared to, so the share does not depend on how busy the shared machine is. The same collection is
then made on LIBERO-goal and LIBERO-object (task 0 of each, the same settings): ``suites`` holds each suite's
steps/s and ``ratio_to_spatial`` its rate over LIBERO-spatial's in this run (issue 36's target: within 20 %).
Prints the summary of ``collect`` and a final JSON line on stdout.

    python bench/collect_throughput.py                        # 1 episode of task 0 (~1-2 min on 2 cores)
    python bench/collect_throughput.py --episodes-per-task 2 --tasks 0 5
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from quick import QUICK, size
from vlaprobe.configs.env import SuiteName

SUITES: tuple[SuiteName, ...] = ("libero_goal", "libero_object")
"""Collected after LIBERO-spatial, task 0 each, to compare their rates with spatial's in one run."""


def _bytes(path: Path, pattern: str) -> tuple[int, int]:
    """(stored bytes, raw bytes) of the arrays matching ``pattern`` in every episode of a store."""
    import zarr

    stored = raw = 0
    for array_dir in path.glob(f"episodes/*/{pattern}"):
        stored += sum(f.stat().st_size for f in array_dir.glob("c.*"))
        a = zarr.open_array(array_dir, mode="r")
        raw += a.nbytes
    return stored, raw


def main() -> None:
    shared_assets = Path(__file__).resolve().parents[2] / "shared" / "libero_assets"
    if (
        "VLAPROBE_LIBERO_ASSETS" not in os.environ and shared_assets.is_dir()
    ):  # offline machines, like the tests
        os.environ["VLAPROBE_LIBERO_ASSETS"] = str(shared_assets)
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tasks", type=int, nargs="+", default=[0])
    parser.add_argument("--episodes-per-task", type=int, default=1)
    parser.add_argument("--image-size", type=int, default=size(256, 64))
    parser.add_argument("--model", default="tiny")
    args = parser.parse_args()

    from vlaprobe.collection.collect import collect
    from vlaprobe.configs.collect import CollectConfig
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.rollout.runner import default_threads

    def config(out: Path, suite: SuiteName, tasks: tuple[int, ...]) -> CollectConfig:
        return CollectConfig(
            out=out,
            policy=PolicyConfig(model=args.model, device="cpu"),
            tasks=tasks,
            episodes_per_task=args.episodes_per_task,
            progress=False,
            env=EnvConfig(suite=suite, image_size=args.image_size, max_steps=size(300, 10)),
            **({"keep_failed": True, "max_tries_per_task": 1} if QUICK else {}),
        )

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "store"
        cfg = config(out, "libero_spatial", tuple(args.tasks))
        start = time.perf_counter()
        r = collect(cfg)
        wall = time.perf_counter() - start
        step_time = r.episode_seconds + r.write_seconds
        sizes = {name: _bytes(out, name) for name in ("hidden", "image")}
        total = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
        files = sum(1 for f in out.glob("episodes/*/**/*") if f.is_file())
        rates = {"libero_spatial": r.steps / step_time}
        for suite in SUITES:
            other = collect(config(Path(tmp) / suite, suite, (0,)))
            rates[suite] = other.steps / (other.episode_seconds + other.write_seconds)
    episodes = max(1, r.episodes_run)
    print(
        json.dumps(
            {
                "episodes": r.episodes_run,
                "successes": sum(s for s, _ in r.kept.values()),
                "steps": r.steps,
                "steps_per_s": round(r.steps / step_time, 3),
                "steps_per_s_with_startup": round(r.steps / wall, 3),
                "step_ms": round(1000 * step_time / max(1, r.steps), 1),
                "label_ms_per_step": round(1000 * r.label_seconds / max(1, r.steps), 2),
                "write_s_per_episode": round(r.write_seconds / episodes, 3),
                "label_write_share": round((r.label_seconds + r.write_seconds) / step_time, 4),
                "target_share": 0.05,
                "hidden_compression": round(sizes["hidden"][0] / max(1, sizes["hidden"][1]), 3),
                "image_compression": round(sizes["image"][0] / max(1, sizes["image"][1]), 3),
                "store_bytes_per_step": round(total / max(1, r.steps)),
                "files_per_episode": round(files / episodes, 1),
                "torch_threads": cfg.threads or default_threads(cfg.workers),
                "cpu_count": os.cpu_count(),
                "suites": {suite: round(rate, 3) for suite, rate in rates.items()},
                "ratio_to_spatial": {
                    suite: round(rate / rates["libero_spatial"], 3) for suite, rate in rates.items()
                },
            }
        )
    )


if __name__ == "__main__":
    main()
