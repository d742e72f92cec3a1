"""`vlaprobe serve`: load the probes and the observed model, then serve the live monitor on uvicorn.

:func:`build_engine` is the composition root: probes -> readout, the cognition per episode, the simulator
with the model, an optional activation store for replays. Tests pass small fakes for the model and the
simulator and keep everything else real.
"""

from __future__ import annotations

import ipaddress
import os
import socket
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe import __version__
from vlaprobe.cognition.plan import TaskGoal
from vlaprobe.configs.checks import check_serve, step_limit
from vlaprobe.configs.env import same_suite
from vlaprobe.configs.monitor import CognitionConfig
from vlaprobe.configs.serve import ServeConfig
from vlaprobe.configs.takeover import TakeoverConfig
from vlaprobe.envs.base import TaskEnv
from vlaprobe.envs.checks import check_inits
from vlaprobe.errors import VlaprobeError
from vlaprobe.live import protocol as P
from vlaprobe.live.app import Engine, Limits, create_app
from vlaprobe.live.pipeline import EpisodeSpec, MakeCognition, Reading, StepBuilder
from vlaprobe.live.replay import StoreReplays
from vlaprobe.live.sources import Simulator, StoreEpisodes
from vlaprobe.live.takeover import LiveTakeovers
from vlaprobe.locks import lock_folder
from vlaprobe.policies.base import VLAPolicy
from vlaprobe.rollout.runner import MakeDriver, default_threads
from vlaprobe.symbols import HEADS, Goal

if TYPE_CHECKING:
    from vlaprobe.cognition import Cognition, CognitionStep
    from vlaprobe.probes.probeset import ProbeSet


class ProbeReading:
    """The probes' readout (``vlaprobe.cognition.readout``, shared with ``vlaprobe cognition``) as a Readout."""

    def __init__(self, probes: ProbeSet, layers: dict[str, int] | None = None) -> None:
        from vlaprobe.cognition.readout import ProbeReadout

        self.readout = ProbeReadout(probes, layers=layers)
        self.layers = {h: int(v) for h, v in self.readout.layers.items()}
        self.threshold = float(probes.threshold)
        self.probed = {h: np.asarray(self.readout.probed[h], bool) for h in HEADS}

    def read(self, hidden: np.ndarray) -> dict[str, Reading]:
        a = self.readout.assign(hidden)
        return {h: Reading(values=a.values[h], probs=a.probs[h], probed=a.probed[h]) for h in HEADS}


class DiarcCognition:
    """A :class:`vlaprobe.cognition.Cognition` whose belief diffs are spelled as DIARC terms (``left_of(a,b)``)."""

    def __init__(self, cognition: Cognition) -> None:
        from vlaprobe.cognition import diarc_term

        self.cognition, self._term = cognition, diarc_term
        self.subgoals = list(cognition.subgoals.states())

    def step(self, object_values: np.ndarray, action_values: np.ndarray) -> CognitionStep:
        s = self.cognition.step(object_values, action_values)
        term = self._term
        return replace(s, asserted=tuple(map(term, s.asserted)), retracted=tuple(map(term, s.retracted)))


def cognition_factory(config: CognitionConfig | None = None) -> MakeCognition:
    """Per episode: a fresh :class:`vlaprobe.cognition.Cognition` over the episode's atoms and goal, built as
    ``vlaprobe cognition`` builds it (predictions: with the probes' ``probed`` mask; truth: without)."""
    from vlaprobe.cognition import Cognition

    def make(
        atoms: dict[str, list[str]], goal: TaskGoal, probed: dict[str, np.ndarray] | None
    ) -> DiarcCognition:
        return DiarcCognition(Cognition(atoms["object"], atoms["action"], goal, config, probed=probed))

    return make


def check_cognition(config: CognitionConfig, probes: ProbeSet) -> None:
    """Build the cognition once over the probes' atoms so that a bad rules file (syntax, not UTF-8, grounding
    or solving beyond its budget) is refused when the server starts, in one line, not at every ``start``."""
    from vlaprobe.cognition import Cognition
    from vlaprobe.symbols.vocabulary import parse_atom

    atoms = {h: probes.atom_names(h) for h in HEADS}
    pairs = [args for pred, args in map(parse_atom, atoms["object"]) if pred == "on" and len(args) == 2]
    if pairs:  # the goal only adds one fact; each task's own is checked when its first episode starts
        cog = Cognition(atoms["object"], atoms["action"], Goal(*pairs[0]), config)
        cog.step(np.zeros(len(atoms["object"]), bool), np.zeros(len(atoms["action"]), bool))


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _token_from_file(path: Path) -> str:
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "not UTF-8 text"
        raise VlaprobeError(f"cannot read --token-file {path} ({reason}); write the secret into it") from None
    token = lines[0].strip() if lines else ""
    if not token:
        raise VlaprobeError(f"--token-file {path} is empty; write the secret on its first line")
    return token


def resolve_token(cfg: ServeConfig) -> str | None:
    """The secret: --token, else the first line of --token-file, else $VLAPROBE_TOKEN (None: no token)."""
    if cfg.token_file is not None:
        token: str | None = _token_from_file(cfg.token_file)
    else:
        token = cfg.token or os.environ.get("VLAPROBE_TOKEN") or None
    if not _is_loopback(cfg.host) and not token:
        raise VlaprobeError(
            f"--host {cfg.host} is reachable from other machines: set a secret in $VLAPROBE_TOKEN or a "
            "--token-file (or bind 127.0.0.1)"
        )
    return token


def load_probes(cfg: ServeConfig) -> ProbeSet:
    from vlaprobe.probes import ProbeSet
    from vlaprobe.probes.probeset import META_FILE

    if cfg.probes.is_file():
        raise VlaprobeError(
            f"--probes {cfg.probes} is a file, not a folder; pass the folder vlaprobe train wrote"
        )
    if not (cfg.probes / META_FILE).is_file():
        raise VlaprobeError(
            f"no probes in {cfg.probes}; run `vlaprobe run` first (or pass --probes DIR from vlaprobe train)"
        )
    return ProbeSet.load(cfg.probes, suite=cfg.env.suite)


def build_engine(
    cfg: ServeConfig,
    probes: ProbeSet,
    *,
    policy: VLAPolicy | None = None,
    make_env: Callable[[int], TaskEnv] | None = None,
    tasks: dict[int, str] | None = None,
    num_init_states: int | None = None,
    make_driver: MakeDriver | None = None,
) -> Engine:
    """Everything the app serves. Without ``policy``/``make_env``/``tasks`` the real model and LIBERO are used."""
    check_cognition(cfg.cognition, probes)  # cached: main's check made the same program
    layers = {h: v for h, v in (("object", cfg.object_layer), ("action", cfg.action_layer)) if v is not None}
    readout = ProbeReading(probes, layers or None)
    make_cognition = cognition_factory(cfg.cognition)

    def make_builder(spec: EpisodeSpec, episode_id: str) -> StepBuilder:
        takeovers = (
            None if spec.takeover == "none" else LiveTakeovers(cfg.intervention, spec.seed, spec.max_steps)
        )
        return StepBuilder(spec, episode_id, readout, make_cognition, takeovers)

    if policy is None:
        import torch

        from vlaprobe.configs.policy import PolicyConfig, pooling_of
        from vlaprobe.policies import make_policy

        torch.set_num_threads(cfg.threads or default_threads(1))
        policy = make_policy(
            PolicyConfig(
                model=cfg.model, pooling=pooling_of(probes.pooling), device=cfg.device, seed=cfg.seed
            ),
            cfg.env.suite,
        )
    probes.check(model_id=policy.model_id, pooling=policy.pooling)
    no_expert: dict[int, str] = {}  # tasks whose goal no expert skill handles (read from the BDDL files)
    if make_env is None or tasks is None:
        from vlaprobe.envs import make_env as make_task_env
        from vlaprobe.envs.libero import num_init_states as init_states
        from vlaprobe.envs.libero import suite_tasks

        tasks = dict(suite_tasks(cfg.env.suite))
        num_init_states = init_states(cfg.env.suite, 0)  # no simulator needed
        if cfg.env.suite != "libero_spatial":  # every LIBERO-spatial goal is the rim pick's
            from vlaprobe.experts.planner import unplannable_tasks

            no_expert = unplannable_tasks(cfg.env, tuple(tasks))

        env_cfg = replace(cfg.env, layout_seed=cfg.seed)  # sampled layouts as collect --seed's

        def make_env(task: int) -> TaskEnv:
            return make_task_env(task, env_cfg)

    extra = {} if make_driver is None else {"make_driver": make_driver}
    atoms = {
        h: probes.atom_names(h) for h in HEADS
    }  # a union suite's: every episode's, undefined ones marked
    sim = Simulator(
        policy,
        make_env,
        tasks,
        max_steps=cfg.env.max_steps,
        post_success_steps=cfg.post_success_steps,
        seed=cfg.seed,
        step_limit=step_limit(cfg.env.settle_steps),
        num_init_states=num_init_states,
        suite=cfg.env.suite,
        takeover=cfg.intervention,
        atoms=atoms,
        no_expert=no_expert,
        **extra,
    )
    replays = None if cfg.store is None else store_replays(cfg.store, probes, make_builder)
    kept = {h: set(probes.atoms(h)) for h in HEADS}
    hello = P.Hello(
        version=__version__,
        suite=cfg.env.suite,
        tasks=[P.TaskInfo(index=i, instruction=s) for i, s in sorted(tasks.items())],
        model_id=policy.model_id,
        probes=P.ProbeInfo(
            layers=P.HeadInts(**readout.layers),
            threshold=readout.threshold,
            atoms=P.HeadNames(**atoms),
            probed=P.HeadFlags(**{h: [a in kept[h] for a in atoms[h]] for h in HEADS}),
        ),
        image_hz=cfg.image_hz,
        num_init_states=int(num_init_states or 0),
        drivers=["policy"] if cfg.intervention.takeover != "none" else ["expert", "policy"],
        default_driver=cfg.driver,
        running=None,
        takeover=takeover_settings(cfg.intervention),
    )
    return Engine(
        hello=hello,
        simulator=sim,
        make_builder=make_builder,
        recordings=recordings_folder(cfg),
        replays=replays,
    )


def takeover_settings(cfg: TakeoverConfig) -> P.TakeoverSettings | None:
    """hello.takeover: the server's --takeover (None without)."""
    if cfg.takeover == "none":
        return None
    return P.TakeoverSettings(
        mode=cfg.takeover,
        steps=cfg.takeover_steps,
        until=cfg.takeover_until,
        most=cfg.takeover_most,
        stall=cfg.takeover_stall,
        hold=cfg.takeover_hold,
        on=list(cfg.takeover_on),
        count=cfg.takeover_count,
    )


def recordings_folder(cfg: ServeConfig) -> Path:
    """Where the server records its live episodes (``--recordings``, default ``live`` beside the probes)."""
    return cfg.recordings if cfg.recordings is not None else cfg.probes.parent / "live"


def store_replays(store: Path, probes: ProbeSet, make_builder: Callable[..., StepBuilder]) -> StoreReplays:
    """The store's episodes for replay: checked intact (the repair advice otherwise) and matching the probes."""
    episodes = StoreEpisodes(store)
    same_suite(f"--store {store}", episodes.store.suite, f"the probes in {probes.where}", probes.suite)
    probes.check(model_id=episodes.store.model_id)
    for h in HEADS:
        if episodes.atoms[h] != probes.atom_names(h):
            raise VlaprobeError(
                f"the probes' {h} atoms differ from store {store}'s; pass the store the probes were "
                "trained on (--store) or its probes (--probes)"
            )
    return StoreReplays(episodes, make_builder)


def limits_of(cfg: ServeConfig, token: str | None) -> Limits:
    return Limits(
        token=token,
        origins=tuple(cfg.origins),
        host=cfg.host,
        max_message_bytes=cfg.max_message_bytes,
        image_hz=cfg.image_hz,
        replay_hz=cfg.replay_hz,
        default_driver=cfg.driver,
        seed=cfg.seed,
    )


def _listen(host: str, port: int) -> socket.socket:
    """The server's listening socket (bound here, so a busy port is one clear line and --port 0 works)."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise VlaprobeError(f"cannot listen on {host}:{port} ({exc.strerror}); pass another --port") from None
    return sock


def run_server(app: object, sock: socket.socket, max_message_bytes: int = 65536) -> None:
    """Serve ``app`` on the bound ``sock`` until SIGINT or SIGTERM (the app's shutdown interrupts a solve)."""
    import uvicorn

    config = uvicorn.Config(app, ws_max_size=max_message_bytes, log_level="warning")  # type: ignore[arg-type]
    uvicorn.Server(config).run(sockets=[sock])


def main(cfg: ServeConfig) -> int:
    """Load everything, print the address, serve until interrupted."""
    check_serve(cfg)
    check_inits(cfg.env, ())
    token = resolve_token(cfg)
    limits = limits_of(cfg, token)
    probes = load_probes(cfg)
    check_cognition(cfg.cognition, probes)  # a bad rules file: refused before the port and the model
    sock = _listen(cfg.host, cfg.port)  # before the model loads: a busy port fails at once
    try:
        # one server records into a folder: a second one on it is refused before its model loads (the lock
        # names the command without its arguments, which may hold a --token)
        lock = lock_folder(
            recordings_folder(cfg), "--recordings", command=f"vlaprobe serve on port {cfg.port}"
        )
    except BaseException:
        sock.close()
        raise
    try:
        app = create_app(build_engine(cfg, probes), limits)
        port = sock.getsockname()[1]
        shown = f"[{cfg.host}]" if ":" in cfg.host else cfg.host
        query = "?token=<token>" if token else ""
        print(
            f"vlaprobe live monitor: http://{shown}:{port}/{query}  (WebSocket ws://{shown}:{port}/ws)",
            flush=True,
        )
        run_server(app, sock, cfg.max_message_bytes)
    finally:
        sock.close()
        lock.release()
    return 0
