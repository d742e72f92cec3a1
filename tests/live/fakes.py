"""A server on fakes: the collection tests' fake simulator and model, run through the real step loop."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from tests.collection import fakes

from vlaprobe.configs.serve import ServeConfig
from vlaprobe.live import protocol as P
from vlaprobe.live.app import Engine, Limits, create_app
from vlaprobe.live.pipeline import EpisodeSpec, Reading, StepBuilder
from vlaprobe.live.sources import Simulator

FakeEnv, FakePolicy, fake_driver, fake_tasks = (
    fakes.FakeEnv,
    fakes.FakePolicy,
    fakes.fake_driver,
    fakes.fake_tasks,
)
SUCCESS_INIT = next(i for i in range(fakes.NUM_INITS) if fakes.succeeds(0, i))
"""An init state from which task 0 succeeds (after ``fakes.success_step(0, init)`` steps)."""
FAIL_INIT = next(i for i in range(fakes.NUM_INITS) if not fakes.succeeds(0, i))
"""An init state from which task 0 never succeeds: the episode runs its whole step budget."""


def episode_length(task: int, init: int) -> int:
    return fakes.success_step(task, init) + 1


class SignReadout:
    """A stand-in readout: atom i is predicted true when hidden[layer, i % hidden] > 0."""

    def __init__(self, atoms: dict[str, list[str]], layers: dict[str, int]) -> None:
        self.atoms, self.layers, self.threshold = atoms, layers, 0.5
        self.probed = {h: np.arange(len(names)) % 5 != 4 for h, names in atoms.items()}

    def read(self, hidden: np.ndarray) -> dict[str, Reading]:
        out = {}
        for h, names in self.atoms.items():
            x = np.asarray(hidden, np.float32)[self.layers[h]]
            idx = np.arange(len(names)) % x.shape[-1]
            p = 1 / (1 + np.exp(-x[idx]))
            probed = self.probed[h]
            out[h] = Reading(values=(p > 0.5) & probed, probs=np.where(probed, p, np.nan), probed=probed)
        return out


class EchoCognition:
    """A stand-in cognition: beliefs are the true atoms, one rule fires while the first atom holds."""

    def __init__(self, atoms: dict[str, list[str]], goal: Any, probed: Any) -> None:
        self.names = atoms["object"] + atoms["action"]
        self.prev: set[str] = set()
        self.t = -1
        self.subgoals = [SimpleNamespace(index=0, name="reach"), SimpleNamespace(index=1, name="grasp")]

    def step(self, obj: np.ndarray, act: np.ndarray) -> Any:
        self.t += 1
        now = {n for n, v in zip(self.names, np.concatenate([obj, act]), strict=True) if v}
        asserted, retracted = sorted(now - self.prev), sorted(self.prev - now)
        self.prev = now
        first = self.names[0] in now
        return SimpleNamespace(
            asserted=asserted,
            retracted=retracted,
            violations=[
                SimpleNamespace(rule="first", message="first atom holds", atoms=[self.names[0]], since=self.t)
            ]
            if first
            else [],
            subgoals=[SimpleNamespace(index=g.index, name=g.name, status="active") for g in self.subgoals],
            progress=0.5,
            events=[SimpleNamespace(kind="stalled", t=self.t, message="x")] if self.t == 1 else [],
            goal_reached=self.t == 2,
        )


def fake_engine(
    tmp: Path, *, step_seconds: float = 0.0, readout: Any = None, make_cognition: Any = None
) -> Engine:
    """An engine on the fake simulator and model (real step loop, hub, session, recorder)."""
    env0 = FakeEnv(0, None)
    vocab = env0.labeler.vocabulary
    atoms = {"object": list(vocab.object_atoms), "action": list(vocab.action_atoms)}
    policy = FakePolicy(SimpleNamespace(pooling="last_prompt", seed=0))
    readout = readout or SignReadout(atoms, {"object": 2, "action": 3})
    make_cognition = make_cognition or EchoCognition

    def make_builder(spec: EpisodeSpec, episode_id: str) -> StepBuilder:
        return StepBuilder(spec, episode_id, readout, make_cognition)

    def make_env(task: int) -> Any:
        env = FakeEnv(task, None)
        env.delay = step_seconds
        return env

    sim = Simulator(policy, make_env, fake_tasks(None), max_steps=40, make_driver=fake_driver)
    hello = P.Hello(
        version="test",
        tasks=[P.TaskInfo(index=i, instruction=s) for i, s in fake_tasks(None).items()],
        model_id="fake",
        probes=P.ProbeInfo(
            layers=P.HeadInts(**readout.layers),
            threshold=0.5,
            atoms=P.HeadNames(**atoms),
            probed=P.HeadFlags(**{h: [True] * len(a) for h, a in atoms.items()}),
        ),
        image_hz=10.0,
        num_init_states=fakes.NUM_INITS,
        drivers=["expert", "policy"],
        default_driver="expert",
        running=None,
    )
    return Engine(hello=hello, simulator=sim, make_builder=make_builder, recordings=tmp / "live")


def fake_app(tmp: Path, limits: Limits | None = None, **kw: Any) -> Any:
    return create_app(fake_engine(tmp, **kw), limits or Limits(image_hz=1000.0))


def local_client(app: Any) -> Any:
    """Starlette's test client, sending ``Host: 127.0.0.1`` (the server refuses other hosts; the plain test
    client says "testserver", and its WebSocket connects always do)."""
    from fastapi.testclient import TestClient

    class Local(TestClient):
        def websocket_connect(self, url: str, *args: Any, **kw: Any) -> Any:
            return super().websocket_connect(
                "ws://127.0.0.1" + url if url.startswith("/") else url, *args, **kw
            )

    return Local(app, base_url="http://127.0.0.1")


def serve_config(tmp: Path, **kw: Any) -> ServeConfig:
    return ServeConfig(probes=tmp / "probes", recordings=tmp / "live", **kw)


class LiveServer:
    """The app on a real uvicorn on 127.0.0.1 (a free port), in a thread, for the duration of a ``with``."""

    def __init__(self, app: Any, max_size: int = 65536) -> None:
        import socket

        import uvicorn

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.app = app
        self.server = uvicorn.Server(
            uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning", ws_max_size=max_size)
        )
        self.url = f"ws://127.0.0.1:{self.port}/ws"
        self.http = f"http://127.0.0.1:{self.port}"

    def __enter__(self) -> LiveServer:
        import threading
        import time

        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.02)
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(20)

    def in_loop(self, fn: Any) -> Any:
        """Run ``fn()`` on the server's event loop thread and return its result."""
        import asyncio

        async def call() -> Any:
            return fn()

        return asyncio.run_coroutine_threadsafe(call(), self.app.state.hub.loop).result(10)


def random_probes(
    folder: Path,
    model_id: str,
    num_hidden_states: int,
    hidden_size: int,
    atoms: dict[str, list[str]],
    layer: int = 8,
    seed: int = 0,
    suite: str = "libero_spatial",
) -> Path:
    """A probe folder with random weights for a model's shapes (to test plumbing, not probing); every fifth
    atom is dropped as "near-constant" so the not-probed path is exercised."""
    import torch

    from vlaprobe.probes import ProbeSet
    from vlaprobe.probes.probemeta import HeadMeta, ProbesMeta
    from vlaprobe.probes.results import DroppedAtom

    g = torch.Generator().manual_seed(seed)
    heads, tensors = {}, {}
    for h, names in atoms.items():
        kept = [a for i, a in enumerate(names) if i % 5 != 4]
        dropped = [DroppedAtom(a, 0.0, "near-constant") for a in names if a not in kept]
        heads[h] = HeadMeta(
            atom_names=names,
            kept=kept,
            dropped=dropped,
            best_layer=layer,
            best_metric="f1",
        )
        tensors[f"{h}.weight"] = torch.randn(1, hidden_size, len(kept), generator=g) / hidden_size**0.5
        tensors[f"{h}.bias"] = torch.zeros(1, len(kept))
    meta = ProbesMeta(
        model_id=model_id,
        pooling="last_prompt",
        hidden_size=hidden_size,
        num_hidden_states=num_hidden_states,
        layers=[layer],
        threshold=0.5,
        heads=heads,
        suite=suite,
    )
    return ProbeSet(meta, tensors).save(folder)


def real_engine(cfg: ServeConfig) -> Engine:
    """The real engine (trained probes, cognition, recorder, store replays) over the fake simulator and model."""
    from vlaprobe.live.serve import build_engine, load_probes

    return build_engine(
        cfg,
        load_probes(cfg),
        policy=FakePolicy(SimpleNamespace(pooling="last_prompt", seed=0)),
        make_env=lambda task: FakeEnv(task, None),
        tasks=fake_tasks(None),
        num_init_states=fakes.NUM_INITS,
        make_driver=fake_driver,
    )
