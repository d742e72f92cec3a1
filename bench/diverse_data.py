"""Diverse data (issue 18): sampled placements + perturbations against fixed init states, the data's figures.

Runs the one step loop (``vlaprobe.rollout.run_episode``) with the scripted expert on LIBERO-spatial, a null
observer and no camera (every figure here is about the data and the expert, not a model or an image). Sets:

- ``sampled``: ``--inits sampled`` with the perturbations of ``experiments/diverse.yaml``, sample indices
  0 and 1 of every task, each episode seeded as collection seeds it;
- ``fixed``: fixed init state 0 of four tasks, unperturbed: the CPU-per-step reference;
- ``fixed_store``: the first 2 episodes per task of a fixed-init store (``$VLAPROBE_FIXED_STORE``, default
  ``runs/default/activations``, the default run): its labels give the fixed-init diversity and baselines on
  as many episodes as the sampled set.

Figures: expert success, rejected samples, recovery per perturbation kind (drop: ``grasped`` turns false and
true again and the bowl ends on the plate; knock-off: the goal atom turns false and true again), distinct
object-state vectors and atoms changing within episodes (``vlaprobe.collection.diversity``), the task and
task x time baselines on a within-task episode split (when ``vlaprobe.probes.baselines`` exists), and the
CPU time per step of both sets (process time: robust to other load on the machine). Final line: JSON.

    python bench/diverse_data.py        # 24 episodes on 2 worker processes
    VLAPROBE_BENCH_INITS=sampled-swap python bench/diverse_data.py    # the sampled set with regions permuted
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

import numpy as np

from quick import size

REPO = Path(__file__).resolve().parents[1]
WORKERS = size(2, 1)
TASKS = size(10, 1)
MAX_STEPS = size(300, 15)
IMAGE = 32
SAMPLED_PER_TASK = size(2, 1)  # sample indices 0, 1 of every task (20 episodes)
FIXED_TASKS = size((0, 3, 6, 9), (0,))  # fixed init state 0 of these tasks: the CPU-per-step reference
SAMPLED_INITS = os.environ.get("VLAPROBE_BENCH_INITS", "sampled")
"""``--inits`` of the sampled set: ``sampled`` (default) or ``sampled-swap`` (regions permuted)."""
FIXED_STORE = Path(os.environ.get("VLAPROBE_FIXED_STORE", REPO / "runs" / "default" / "activations"))
"""A fixed-init store (the default run's): its labels give the fixed-init diversity and baselines."""


class Unrendered:
    """The task environment without its camera (8x cheaper steps): the loop gets a blank frame instead."""

    BLANK = np.zeros((IMAGE, IMAGE, 3), np.uint8)

    def __init__(self, env: object) -> None:
        self.env = env

    def __getattr__(self, name: str) -> object:
        return getattr(self.env, name)

    def _blank(self, obs: object) -> object:
        obs.image = self.BLANK  # type: ignore[attr-defined]
        return obs

    def reset(self, init: int) -> object:
        return self._blank(self.env.reset(init))  # type: ignore[attr-defined]

    def step(self, action: np.ndarray) -> object:
        return self._blank(self.env.step(action))  # type: ignore[attr-defined]

    def place_object(self, name: str, xy: tuple[float, float]) -> object:
        return self._blank(self.env.place_object(name, xy))  # type: ignore[attr-defined]


class NullObserver:
    """An observer that computes nothing (the figures are about the data, not a model)."""

    model_id, pooling, num_hidden_states, hidden_size = "none", "last_prompt", 1, 1

    def step(self, image: np.ndarray, instruction: str) -> object:
        from types import SimpleNamespace

        return SimpleNamespace(
            action=np.zeros(7),
            hidden=np.zeros((1, 1), np.float32),
            model_image=image,
            action_tokens=np.zeros(7, np.int64),
        )


def _experiment() -> str:
    import yaml

    return str(yaml.safe_load((REPO / "experiments" / "diverse.yaml").read_text())["collect"]["perturb"])


def _store_records(path: Path, per_task: int) -> list[dict]:
    """The first ``per_task`` episodes of every task of a fixed-init store, as label records."""
    from vlaprobe.collection.store import ActivationStore

    store = ActivationStore.open(path)
    out, seen = [], {}
    for info in store.episodes():
        if seen.setdefault(info.task, 0) >= per_task:
            continue
        seen[info.task] += 1
        a = store.episode(info.key)
        out.append(
            {
                "set": "fixed_store",
                "task": info.task,
                "init": info.init,
                "success": info.success,
                "length": info.length,
                "cpu_s": 0.0,
                "draws": 1,
                "rejected": [],
                "perturbations": [],
                "object": np.asarray(a["object_atoms"]).tolist(),
                "action": np.asarray(a["action_atoms"]).tolist(),
            }
        )
    return out


def run_task(job: tuple[int, str, int, str]) -> list[dict]:
    """Episodes 0..n-1 of one task under one set; one record per episode."""
    task, kind, n, perturb = job
    from vlaprobe.collection.plan import Unit
    from vlaprobe.collection.worker import unit_seed
    from vlaprobe.configs.env import EnvConfig
    from vlaprobe.envs.libero import LiberoTaskEnv
    from vlaprobe.rollout import EpisodeControl, ExpertDriver, run_episode
    from vlaprobe.rollout.perturb import PerturbSpec, episode_perturber
    from vlaprobe.symbols.vocabulary import atom

    records = []
    spec = PerturbSpec.parse(perturb if kind == "sampled" else "")
    inits = SAMPLED_INITS if kind == "sampled" else kind
    with LiberoTaskEnv(task, EnvConfig(render=False, inits=inits)) as env:  # type: ignore[arg-type]
        grasp = env.labeler.vocabulary.action_atoms.index(atom("grasped", env.goal.pick))
        goal = env.labeler.vocabulary.object_atoms.index(atom("on", env.goal.pick, env.goal.place))
        for init in range(n):
            seed = unit_seed(0, Unit(task, init))
            control = EpisodeControl()
            perturber = episode_perturber(spec, seed, env, MAX_STEPS)  # as collection builds it
            obj, act, success = [], [], False
            cpu = time.process_time()
            for r in run_episode(
                Unrendered(env),  # type: ignore[arg-type]
                NullObserver(),
                ExpertDriver(env, seed),
                init=init,
                max_steps=MAX_STEPS,  # type: ignore[arg-type]
                post_success_steps=10,
                control=control,
            ):
                obj.append(r.object_atoms)
                act.append(r.action_atoms)
                success = r.success and r.terminal
                if perturber is not None:
                    perturber.observe(r.t, r.world, bool(r.action_atoms[grasp]), r.success, control)
            cpu = time.process_time() - cpu
            placement = env.last_placement if kind == "sampled" else None
            o, a = np.array(obj), np.array(act)
            records.append(
                {
                    "set": kind,
                    "task": task,
                    "init": init,
                    "success": bool(success),
                    "length": len(o),
                    "cpu_s": cpu,
                    "draws": placement.draws if placement else 1,
                    "rejected": list(placement.rejected) if placement else [],
                    "perturbations": [
                        _outcome(p.kind, p.row, a[:, grasp], o[:, goal], success)
                        for p in (perturber.planned if perturber is not None else [])
                        if p.row is not None
                    ],
                    "object": o.tolist(),
                    "action": a.tolist(),
                }
            )
            print(
                f"{kind} task {task} init {init}: success {success}, {len(o)} rows, "
                f"{len(records[-1]['rejected'])} rejected, {records[-1]['perturbations']}",
                file=sys.stderr,
            )
    return records


def _outcome(kind: str, row: int, grasped: np.ndarray, goal: np.ndarray, success: bool) -> dict:
    """Whether the atom a perturbation hits turned false and true again (and the episode still succeeded)."""
    if kind == "drop":
        after = grasped[row:]
        released = int(np.argmax(~after)) if (~after).any() else None
        recovered = released is not None and bool(after[released:].any()) and success
        return {"kind": kind, "row": row, "released": released is not None, "recovered": recovered}
    if kind == "knock_off":
        hit = not goal[row]
        return {"kind": kind, "row": row, "released": hit, "recovered": hit and bool(goal[-1]) and success}
    return {"kind": kind, "row": row, "released": True, "recovered": success}


def _baselines(records: list[dict]) -> dict[str, dict[str, float]] | None:
    """Task and task x time baselines' balanced accuracy (mean over atoms kept by the 1%/99% filter) on the
    default within-task episode split (seed 0), per head; None without ``vlaprobe.probes.baselines``."""
    try:
        from vlaprobe.probes.baselines import predict_baselines
    except ImportError:
        return None
    from vlaprobe.probes.split import filter_labels, rows_of, split_episodes
    from vlaprobe.symbols import HEADS

    tasks = np.array([r["task"] for r in records])
    episode = np.concatenate([np.full(r["length"], i) for i, r in enumerate(records)])
    (fold,) = split_episodes(tasks, 0.2, 1, 0)
    train, test = rows_of(episode, fold.train), rows_of(episode, fold.test)
    out: dict[str, dict[str, float]] = {}
    for head in HEADS:
        y = np.concatenate([np.array(r[head], bool) for r in records])
        kept = filter_labels(y[train], [str(i) for i in range(y.shape[1])], 0.01, 0.99).kept
        pred = predict_baselines(y[:, kept], episode, tasks, train, test)
        truth = y[test][:, kept]
        out[head] = {name: _balanced_accuracy(truth, p) for name, p in pred.items()}
    return out


def _balanced_accuracy(y: np.ndarray, p: np.ndarray) -> float:
    """Mean balanced accuracy over the atoms of bool (rows, atoms) truth ``y`` and prediction ``p``."""
    from vlaprobe.probes.bootstrap import nan_mean
    from vlaprobe.probes.metrics import confusion_by_group, metrics_from_counts

    counts = confusion_by_group(p[None], y, np.zeros(len(y), np.int64), 1)[0, 0]
    return float(nan_mean(metrics_from_counts(counts)["balanced_accuracy"], 0))


def summarize(records: list[dict]) -> dict:
    from vlaprobe.collection.diversity import diversity

    out: dict = {}
    for kind in ("fixed", "sampled", "fixed_store"):
        rs = [r for r in records if r["set"] == kind]
        if not rs:
            continue
        d = diversity(
            {
                "object": [str(i) for i in range(len(rs[0]["object"][0]))],
                "action": [str(i) for i in range(len(rs[0]["action"][0]))],
            },
            [{"object": np.array(r["object"], bool), "action": np.array(r["action"], bool)} for r in rs],
        )
        perts = [p for r in rs for p in r["perturbations"]]
        by_kind = {
            k: {
                "applied": sum(p["kind"] == k for p in perts),
                "hit": sum(p["kind"] == k and p["released"] for p in perts),
                "recovered": sum(p["kind"] == k and p["recovered"] for p in perts),
            }
            for k in ("drop", "displace", "knock_off")
        }
        rows = sum(r["length"] for r in rs)
        out[kind] = {
            "episodes": len(rs),
            "rows": rows,
            "success_rate": sum(r["success"] for r in rs) / len(rs),
            "draws": sum(r["draws"] for r in rs),
            "rejected": sum(len(r["rejected"]) for r in rs),
            "rejected_rate": sum(len(r["rejected"]) for r in rs) / sum(r["draws"] for r in rs),
            "perturbations": by_kind,
            "distinct_object_states": d.heads["object"].distinct_states,
            "object_atoms_varying": d.heads["object"].varying,
            "action_atoms_varying": d.heads["action"].varying,
            "action_atoms_ever_true": d.heads["action"].ever_true,
            "cpu_ms_per_step": 1000 * sum(r["cpu_s"] for r in rs) / rows,
            "baselines_balanced_accuracy": _baselines(rs) if kind != "fixed" else None,
        }
    if "fixed" in out and "sampled" in out:
        out["cpu_per_step_ratio"] = out["sampled"]["cpu_ms_per_step"] / out["fixed"]["cpu_ms_per_step"]
    return out


def main() -> None:
    perturb = _experiment()
    jobs = [(t, "sampled", SAMPLED_PER_TASK, perturb) for t in range(TASKS)] + [
        (t, "fixed", 1, perturb) for t in FIXED_TASKS
    ]
    start = time.perf_counter()
    with mp.get_context("spawn").Pool(WORKERS) as pool:
        records = [r for chunk in pool.imap_unordered(run_task, jobs) for r in chunk]
    if (FIXED_STORE / "zarr.json").is_file():
        records += _store_records(FIXED_STORE, SAMPLED_PER_TASK)
    result = summarize(records)
    result["wall_s"] = time.perf_counter() - start
    result["perturb"] = perturb
    result["inits"] = SAMPLED_INITS
    dump = os.environ.get("VLAPROBE_BENCH_DUMP")
    if dump:
        Path(dump).write_text(json.dumps(records))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
