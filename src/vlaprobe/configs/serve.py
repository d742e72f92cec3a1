"""Config of ``vlaprobe serve``: the live monitor's WebSocket server."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from vlaprobe.configs.env import EnvConfig
from vlaprobe.configs.monitor import CognitionConfig
from vlaprobe.configs.takeover import TakeoverConfig

LiveDriver = Literal["expert", "policy"]
"""Who acts in a live episode: the scripted expert or the VLA itself (DAgger is for collection only)."""


@dataclass
class ServeConfig:
    """Run LIBERO, the VLA, the probes and the cognition step by step and stream them to WebSocket clients."""

    probes: Path = Path("runs/default/probes")
    """Probe folder written by ``vlaprobe train`` (or ``vlaprobe run``)."""
    model: str = "tiny-libero"
    """The observed model: "tiny-libero" (the shipped trained tiny model), "tiny" (random weights) or an OpenVLA
    checkpoint folder; must be the one the probes were trained on."""
    device: str = "auto"
    """Torch device of the model: "auto", "cpu", "cuda" or "cuda:N"."""
    store: Path | None = None
    """An activation store (``vlaprobe collect``) whose episodes are listed and replayed without the simulator."""
    host: str = "127.0.0.1"
    """Address to bind. An address other than loopback requires a token."""
    port: int = 6006
    """TCP port (the paper's UI connects to 6006)."""
    token: str | None = None
    """Secret that WebSocket connects (``?token=``) and REST calls (``Authorization: Bearer``) must present.
    Default: $VLAPROBE_TOKEN. Required off loopback; optional on it. Prefer $VLAPROBE_TOKEN or --token-file:
    a --token on the command line is visible to every local user in ``ps``."""
    token_file: Path | None = None
    """File holding the token (its first line), instead of --token."""
    origins: tuple[str, ...] = ()
    """Browser Origins allowed besides the server's own address and localhost (e.g. "https://lab.example");
    their host names are also accepted in the Host header (any other name is refused: DNS rebinding)."""
    image_hz: float = 10.0
    """Most images per second sent to one client; intermediate frames are dropped, step states never."""
    replay_hz: float = 10.0
    """Steps per second when a client replays a stored episode (0.5-60)."""
    recordings: Path | None = None
    """Folder of recorded live episodes (one folder per episode). Default: ``live`` beside the probe folder.
    Recordings are private to the server's user: folders 700, files 600."""
    driver: LiveDriver = "expert"
    """Driver of episodes started without one (the paper's client): the scripted expert or the VLA itself
    (--takeover needs "policy")."""
    intervention: Annotated[TakeoverConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=TakeoverConfig)
    """When the scripted expert takes over from the policy (--takeover alarm|random, docs/failures.md): the
    alarm reads the cognition on the probes' predictions; the random control takes --takeover-count."""
    object_layer: int | None = None
    """Hidden state the object probe reads; default: its ``default_layer`` (earliest tied with the best)."""
    action_layer: int | None = None
    """Hidden state the action probe reads; default: its ``default_layer`` (earliest tied with the best)."""
    post_success_steps: int = 10
    """Steps an episode goes on after success (the expert releases the object and lifts the arm), as in
    collection: the goal must hold for the cognition's debounce steps before it counts as reached."""
    max_message_bytes: int = 65536
    """Largest client frame accepted (at least 1024); a larger one closes that connection (1009)."""
    threads: int = 0
    """Torch threads; 0: one per two cores (the simulator needs the rest)."""
    seed: int = 0
    """Seed of random init states and of the tiny model's weights."""
    cognition: CognitionConfig = field(default_factory=CognitionConfig)
    """The belief store, rules (``--cognition.rules FILE`` adds yours) and subgoal tracking, as in `vlaprobe cognition`."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """The simulator (assets, image size, settle steps, ``max_steps`` = the default step budget)."""
