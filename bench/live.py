"""The live monitor's costs and fan-out: probes and cognition per step, message latency to 1 and 8 loopback
clients, the live step rate with 8 clients over the bare step loop's, and what a client that reads nothing
for 10 s does to the others.

- ``probe_ms``: both heads' readout of one step at hidden size 4096 (OpenVLA-7B's), 236 atoms (target <= 1 ms).
- ``cognition_ms``: one step of the cognition (beliefs, rules, subgoals) on the probes' predictions.
- ``latency_p50_ms`` / ``latency_p95_ms`` (``_1``: one client, ``_8``: eight): from a step message being ready
  (its ``ready_at``) to its arrival at a client in another process on 127.0.0.1; a 30 Hz synthetic source
  of LIBERO-shaped steps (real frame, real atoms, the tiny model's hidden states) through the real probes,
  cognition, hub and uvicorn (target p95 <= 20 ms).
- ``rate_ratio``: steps/s of a live episode (LIBERO, tiny model, expert) streamed to 8 clients / steps/s of
  the same step loop run bare in this process, same task, init and step count (target >= 0.9).
- ``slow_client_other_rate_ratio``: the other 7 clients' receive rate while one reads nothing for 10 s,
  over their rate just before (1.0 = unaffected); ``slow_client_lost_states`` must be 0.
- ``store_reads_rate_ratio``: steps/s of a live episode while 8 clients (another process) fetch store episodes
  and their frames in parallel, over the quiet rate of the same episode in the same run (quiet, loaded,
  quiet, loaded, quiet; target >= 0.8); ``store_reads_per_s`` is what the 8 readers got meanwhile.

Runs in ~2-3 minutes on 2 cores. Prints a final JSON line.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import multiprocessing as mp
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from quick import size

STEPS_FAST, HZ_FAST, STEPS_LIVE = size(300, 20), 30.0, size(40, 6)
SLOW_STEPS, PAUSE_AT, PAUSE_S = size(600, 30), size(150, 10), size(10.0, 1.0)
"""The slow-client case: steps of its episode, the step at which one client stops reading, for how long."""
STORE_EPISODES = size(16, 2)


def random_probes(folder: Path, model_id: str, layers: int, hidden: int, atoms: dict[str, list[str]]) -> Any:
    """Probes of the right shapes with random weights (costs do not depend on what probes know)."""
    import torch

    from vlaprobe.probes import ProbeSet
    from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta

    g = torch.Generator().manual_seed(0)
    heads, tensors = {}, {}
    for h, names in atoms.items():
        heads[h] = HeadMeta(atom_names=names, kept=names, best_layer=layers // 2, best_metric="f1")
        tensors[f"{h}.weight"] = torch.randn(1, hidden, len(names), generator=g) / hidden**0.5
        tensors[f"{h}.bias"] = torch.zeros(1, len(names))
    meta = ProbesMeta(
        model_id=model_id, pooling="last_prompt", hidden_size=hidden, num_hidden_states=layers,
        layers=[layers // 2], threshold=0.5, heads=heads,
    )  # fmt: skip
    ProbeSet(meta, tensors).save(folder)
    return ProbeSet.load(folder)


def median_ms(fn: Any, n: int) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


class SyntheticSource:
    """LIBERO-shaped steps at a fixed rate: a real frame and atoms, a few atoms flipping, tiny-model hidden states."""

    def __init__(
        self,
        spec: Any,
        frame: np.ndarray,
        atoms: tuple[np.ndarray, np.ndarray],
        steps: int,
        hz: float,
        hidden: tuple[int, int],
    ):
        self.spec, self.frame, self.atoms, self.steps, self.hz = spec, frame, atoms, steps, hz
        self.hidden = hidden

    def records(self, control: Any) -> Any:
        from vlaprobe.rollout.loop import StepRecord  # the real record: a new field cannot break the bench

        rng = np.random.default_rng(0)
        obj, act = (a.copy() for a in self.atoms)
        next_at = time.monotonic()
        for t in range(self.steps):
            if control.stopped:
                return
            time.sleep(max(0.0, next_at - time.monotonic()))
            next_at += 1.0 / self.hz
            if t % 10 == 0:
                i = rng.integers(len(obj))
                obj[i] = ~obj[i]
            yield StepRecord(
                t=t, step=t, raw_image=None, model_image=self.frame,
                hidden=rng.standard_normal(self.hidden).astype(np.float32), object_atoms=obj.copy(),
                action_atoms=act.copy(), world=None, proprio=None, action=rng.uniform(-1, 1, 7),
                predicted_action=rng.uniform(-1, 1, 7), action_tokens=None, success=False,
                terminal=t == self.steps - 1, perturbed=False, perturbation="", timings=None,
            )  # fmt: skip


# -- clients (in another process, one asyncio loop) ------------------------------------------------
async def _client(url: str, i: int, start: str | None, pause_at: int | None, ready: Any, out: dict) -> None:
    from websockets.asyncio.client import connect

    rows = []
    async with connect(url, max_size=None) as ws:
        await ws.recv()
        ready.release()
        if start is not None:
            await ws.send(start)
        while True:
            msg = json.loads(await ws.recv())
            now = time.time()
            if msg["type"] == "step":
                rows.append(
                    (msg["t"], (now - msg["ready_at"]) * 1e3, now, msg["image"] is not None, msg["ready_at"])
                )
                if msg["t"] == pause_at:
                    await asyncio.sleep(PAUSE_S)  # this client reads nothing for PAUSE_S s
            elif msg["type"] == "episode_end":
                break
            elif msg["type"] == "error":  # the episode failed: fail the bench now, not at the 600 s timeout
                raise RuntimeError(f"client {i}: the server reported: {msg['message']}")
    out[i] = rows


def clients_main(url: str, n: int, start: str | None, pause_at: int | None, ready: Any, results: Any) -> None:
    async def run() -> dict:
        out: dict = {}
        await asyncio.gather(
            *(
                _client(url, i, start if i == 0 else None, pause_at if i == 0 else None, ready, out)
                for i in range(n)
            )
        )
        return out

    results.put(asyncio.run(run()))


def with_clients(url: str, n: int, begin: Any, start: str | None = None, pause_at: int | None = None) -> dict:
    ctx = mp.get_context("spawn")
    ready, results = ctx.Semaphore(0), ctx.Queue()
    proc = ctx.Process(target=clients_main, args=(url, n, start, pause_at, ready, results))
    proc.start()
    for _ in range(n):
        if not ready.acquire(timeout=60):
            raise RuntimeError("clients did not connect")
    if begin is not None:
        begin()
    out = results.get(timeout=600)
    proc.join(30)
    return out


# -- store readers (in another process, 8 threads) -------------------------------------------------
def readers_main(base: str, ids: list[str], n: int, started: Any, stop: Any, results: Any) -> None:
    """``n`` threads, each fetching store episodes (whole, then 4 frames) in a loop until ``stop``."""
    import urllib.error
    import urllib.request

    counts = {"episodes": 0, "frames": 0, "busy": 0, "failed": 0}
    lock = threading.Lock()

    def fetch(url: str) -> int:
        try:
            with urllib.request.urlopen(url, timeout=600) as r:
                r.read()
                return r.status
        except urllib.error.HTTPError as exc:
            return exc.code
        except OSError:  # refused or timed out: counted as failed
            return 0

    def reader(i: int) -> None:
        k = i
        while not stop.is_set():
            eid = ids[k % len(ids)]
            k += 1
            status = fetch(f"{base}/api/episodes/{eid}")
            with lock:
                counts["episodes" if status == 200 else "busy" if status == 503 else "failed"] += 1
                if counts["episodes"]:  # any reader's first episode (a check of one thread's could miss it)
                    started.set()
            for t in size((0, 5, 10, 15), (0, 3, 6, 9)):  # frames inside the episodes (10 steps when quick)
                status = fetch(f"{base}/api/episodes/{eid}/frames/{t}")
                with lock:
                    counts["frames" if status == 200 else "busy" if status == 503 else "failed"] += 1

    threads = [threading.Thread(target=reader, args=(i,)) for i in range(n)]
    t0 = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    results.put({**counts, "seconds": time.monotonic() - t0})


def synthetic_store(
    path: Path,
    frame: np.ndarray,
    atoms: dict,
    obj: np.ndarray,
    act: np.ndarray,
    goal: Any,
    shape: tuple[str, int, int],
) -> list[str]:
    """A store of 16 LIBERO-shaped episodes (150 steps, real frame and atoms, random hidden states of the
    observer's ``shape``: model id, hidden states, hidden size)."""

    from vlaprobe.collection.store import EpisodeInfo, episode_key
    from vlaprobe.collection.writer import StoreWriter

    model_id, layers, hidden = shape
    meta = {
        "atom_names": atoms, "model_id": model_id, "model": {"name": model_id}, "num_hidden_states": layers,
        "hidden_size": hidden, "pooling": "last_prompt", "driver": "expert", "suite": "libero_spatial",
        "env": {"image_size": 256}, "seed": 0,
    }  # fmt: skip
    rng = np.random.default_rng(2)
    length = size(150, 10)
    with StoreWriter.open(path, meta) as w:
        for init in range(STORE_EPISODES):
            o = np.repeat(obj[None], length, 0)
            o[rng.integers(length, size=20), rng.integers(len(obj), size=20)] ^= True
            arrays = {
                "hidden": rng.standard_normal((layers, length, hidden)).astype(np.float16),
                "object_atoms": o, "action_atoms": np.repeat(act[None], length, 0),
                "image": np.repeat(frame[None], length, 0), "action": rng.uniform(-1, 1, (length, 7)).astype(np.float32),
                "predicted_action": rng.uniform(-1, 1, (length, 7)).astype(np.float32),
                "step": np.arange(length, dtype=np.int32),
            }  # fmt: skip
            info = EpisodeInfo(episode_key(0, init), 0, init, 0, False, length, seed=init, driver="expert")
            w.write_episode(info, arrays, {"instruction": "bench", "goal": dataclasses.asdict(goal)})
    return ["store-" + episode_key(0, init) for init in range(STORE_EPISODES)]


def store_reads_case(url: str, base: str, ids: list[str], start: str, wait_idle: Any) -> dict:
    """The live step rate quiet and while 8 clients fetch store episodes, alternated in one run."""
    ctx = mp.get_context("spawn")

    def live_rate() -> float:
        rows = with_clients(url, 1, None, start=start)
        wait_idle()
        ready = sorted({r[0]: r[4] for r in rows[0]}.items())
        return (len(ready) - 2) / (ready[-1][1] - ready[1][1])

    quiet, loaded, reads = [live_rate()], [], []
    for _ in range(2):
        started, stop, results = ctx.Event(), ctx.Event(), ctx.Queue()
        proc = ctx.Process(target=readers_main, args=(base, ids, 8, started, stop, results))
        proc.start()
        if not started.wait(120):
            raise RuntimeError("the store readers fetched no episode in 120 s")
        loaded.append(live_rate())
        stop.set()
        reads.append(results.get(timeout=600))
        proc.join(60)
        quiet.append(live_rate())
    ratios = [x / statistics.mean(quiet[i : i + 2]) for i, x in enumerate(loaded)]
    per_s = [r["episodes"] / r["seconds"] for r in reads]
    return {
        "store_reads_rate_ratio": round(statistics.mean(ratios), 3),
        "store_reads_live_steps_per_s": [round(x, 2) for x in loaded],
        "store_reads_quiet_steps_per_s": [round(x, 2) for x in quiet],
        "store_reads_per_s": round(statistics.mean(per_s), 2),
        "store_reads_busy": sum(r["busy"] for r in reads),
        "store_reads_failed": sum(r["failed"] for r in reads),
    }


def latency(rows: dict) -> tuple[float, float]:
    lat = np.array([r[1] for v in rows.values() for r in v])
    return round(float(np.percentile(lat, 50)), 2), round(float(np.percentile(lat, 95)), 2)


def main() -> None:
    import uvicorn

    shared = Path(__file__).resolve().parents[2] / "shared" / "libero_assets"
    if "VLAPROBE_LIBERO_ASSETS" not in os.environ and shared.is_dir():
        os.environ["VLAPROBE_LIBERO_ASSETS"] = str(shared)
    from vlaprobe.cognition import Cognition
    from vlaprobe.cognition.plan import task_goal
    from vlaprobe.cognition.readout import ProbeReadout
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.configs.serve import ServeConfig
    from vlaprobe.envs import make_env
    from vlaprobe.live.app import create_app
    from vlaprobe.live.pipeline import EpisodeSpec
    from vlaprobe.live.serve import build_engine, limits_of
    from vlaprobe.policies import make_policy
    from vlaprobe.rollout import EpisodeControl, make_driver, run_episode

    tmp = Path(tempfile.mkdtemp(prefix="bench-live-"))
    cfg = ServeConfig(probes=tmp / "probes", device="cpu", recordings=tmp / "live")
    env = make_env(0, cfg.env)
    vocab = env.labeler.vocabulary
    atoms = {"object": list(vocab.object_atoms), "action": list(vocab.action_atoms)}
    first = env.reset(0)
    goal = task_goal(env.goal_conjunction, env.scene)  # what the live source builds for the episode

    # probes and cognition alone
    big = ProbeReadout(random_probes(tmp / "big", "openvla-7b", 33, 4096, atoms))
    hidden = np.random.default_rng(0).standard_normal((33, 4096)).astype(np.float32)
    probe_ms = median_ms(lambda: big.assign(hidden), size(300, 5))
    cog = Cognition(atoms["object"], atoms["action"], goal, cfg.cognition)
    obj, act = env.labeler(env.world_state())
    rng = np.random.default_rng(1)

    state = obj.copy()

    def cog_step() -> None:
        state[rng.integers(len(state), size=3)] ^= True  # a few lasting flips per step, as from probes
        cog.step(state, act)

    cognition_ms = median_ms(cog_step, size(300, 5))

    # the server: real engine (the default observer, LIBERO, random probes of its shapes, a store); the probes
    # and the store take the observer's id and shapes from the loaded model, so a new default cannot break it
    policy = make_policy(PolicyConfig(model=cfg.model, device="cpu", seed=cfg.seed))
    shape = (policy.model_id, policy.num_hidden_states, policy.hidden_size)
    probes = random_probes(cfg.probes, *shape, atoms)
    frame = np.ascontiguousarray(first.image[::-1, ::-1][16:240, 16:240])
    store_ids = synthetic_store(tmp / "store", frame, atoms, obj, act, env.goal, shape)
    cfg = dataclasses.replace(cfg, store=tmp / "store")
    engine = build_engine(cfg, probes, policy=policy)
    app = create_app(engine, limits_of(cfg, None))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    threading.Thread(target=server.run, daemon=True).start()
    while not server.started:
        time.sleep(0.05)
    port = server.servers[0].sockets[0].getsockname()[1]
    url = f"ws://127.0.0.1:{port}/ws"
    session = app.state.session
    spec = EpisodeSpec(
        task=0, instruction=env.instruction, init=0, driver="synthetic", max_steps=STEPS_FAST, source="live",
        suite=cfg.env.suite, goal=goal, atoms=atoms,
    )  # fmt: skip

    def synthetic(steps: int) -> Any:
        return lambda: session.start(
            0,
            "bench",
            lambda: SyntheticSource(spec, frame, (obj, act), steps, HZ_FAST, shape[1:]),
            EpisodeControl(),
            False,
        )

    def wait_idle() -> None:
        while session.running is not None:
            time.sleep(0.05)

    r1 = with_clients(url, 1, synthetic(STEPS_FAST))
    wait_idle()
    r8 = with_clients(url, 8, synthetic(STEPS_FAST))
    wait_idle()
    pause_at = PAUSE_AT  # 5 s in; 10 s without reading; the episode lasts 20 s
    rs = with_clients(url, 8, synthetic(SLOW_STEPS), pause_at=pause_at)
    wait_idle()
    pause_start = next(r[2] for r in rs[0] if r[0] == pause_at)
    before = [sum(pause_start - 3 <= r[2] < pause_start for r in rs[i]) / 3 for i in range(1, 8)]
    during = [sum(pause_start <= r[2] < pause_start + PAUSE_S for r in rs[i]) / PAUSE_S for i in range(1, 8)]
    slow_images = sum(r[3] for r in rs[0] if r[0] > pause_at)

    # rate: the bare step loop vs live with 8 clients, same task/init/steps, bare twice around live
    def bare() -> float:
        driver = make_driver("expert", env, engine.simulator.policy, 0)
        stamps = [
            time.perf_counter()
            for _ in run_episode(env, engine.simulator.policy, driver, init=0, max_steps=STEPS_LIVE)
        ]
        return (len(stamps) - 2) / (stamps[-1] - stamps[1])  # from the second step: no reset

    start = json.dumps({"type": "start", "task": 0, "init": 0, "driver": "expert", "max_steps": STEPS_LIVE})
    bares, lives = [bare()], []
    for _ in range(2):  # bare, live, bare, live, bare: the machine's load drifts; compare neighbours
        rl = with_clients(url, 8, None, start=start)
        wait_idle()
        ready = sorted({r[0]: r[4] for r in rl[0]}.items())
        lives.append((len(ready) - 2) / (ready[-1][1] - ready[1][1]))
        bares.append(bare())
    ratios = [live / statistics.mean(bares[i : i + 2]) for i, live in enumerate(lives)]
    store_reads = store_reads_case(url, f"http://127.0.0.1:{port}", store_ids, start, wait_idle)
    server.should_exit = True
    result = {
        "probe_ms": round(probe_ms, 4),
        "cognition_ms": round(cognition_ms, 3),
        "latency_p50_ms_1": latency(r1)[0],
        "latency_p95_ms_1": latency(r1)[1],
        "latency_p50_ms_8": latency(r8)[0],
        "latency_p95_ms_8": latency(r8)[1],
        "latency_p50_ms": latency(r8)[0],
        "latency_p95_ms": latency(r8)[1],
        "rate_ratio": round(statistics.mean(ratios), 3),
        "live_steps_per_s": [round(x, 2) for x in lives],
        "bare_steps_per_s": [round(x, 2) for x in bares],
        "slow_client_other_rate_before": round(statistics.mean(before), 2),
        "slow_client_other_rate_during": round(statistics.mean(during), 2),
        "slow_client_other_rate_ratio": round(statistics.mean(during) / statistics.mean(before), 3),
        "slow_client_lost_states": SLOW_STEPS - len(rs[0]),
        "slow_client_images_after_pause": int(slow_images),
        **store_reads,
        "steps_per_client": {"fast": STEPS_FAST, "hz": HZ_FAST, "live": STEPS_LIVE},
        "load_average_1min": round(os.getloadavg()[0], 2),
        "cpus": os.cpu_count(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
