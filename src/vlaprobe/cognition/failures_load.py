"""The stored episodes as `vlaprobe failures` reads them: the cognition run over their atoms (or the probes'
predictions), one layer's hidden states and, with ``--token-model``, the action-token distribution of every step
recomputed from the stored images by the store's observer (the store keeps the chosen token ids only)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vlaprobe.cognition.failure_scores import EpisodeData
from vlaprobe.cognition.failures import TokenSource
from vlaprobe.configs.failures import FailuresConfig
from vlaprobe.errors import VlaprobeError

if TYPE_CHECKING:
    from vlaprobe.collection.store import ActivationStore, StoredEpisode
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy


def token_observer(store: ActivationStore, model: str) -> OpenVLAPolicy:
    """The store's observer, loaded to recompute token distributions: ``model`` must be the model that recorded
    the store (its ``model_id``), with the store's pooling."""
    from vlaprobe.configs.policy import PolicyConfig
    from vlaprobe.policies.factory import make_policy
    from vlaprobe.policies.openvla.policy import OpenVLAPolicy

    policy = make_policy(PolicyConfig(model=model, pooling=store.pooling), store.suite)  # type: ignore[arg-type]
    if not isinstance(policy, OpenVLAPolicy) or policy.model_id != store.model_id:
        found = getattr(policy, "model_id", model)
        raise VlaprobeError(
            f"--token-model {model} is {found}, but {store.path} was observed by {store.model_id}: pass that model"
        )
    return policy


def episode_tokens(policy: OpenVLAPolicy, ep: StoredEpisode, path: Path) -> tuple[np.ndarray, int]:
    """(T, 2) mean entropy and top probability of the action tokens at every stored step, and how many steps'
    recomputed greedy tokens equal the stored ``action_tokens``."""
    if "image" not in ep or "action_tokens" not in ep:
        raise VlaprobeError(
            f"episode {ep.info.key} of {path} keeps no images or action tokens (a re-observed store?);"
            " --token-model needs both: use the store the observer recorded"
        )
    stats, tokens = policy.token_uncertainty(np.asarray(ep["image"]), ep.attributes.instruction)
    same = int(np.all(tokens == np.asarray(ep["action_tokens"], np.int64), axis=1).sum())
    return stats, same


def load_episodes(cfg: FailuresConfig) -> tuple[list[EpisodeData], str, int, TokenSource | None]:
    """Every stored episode as the predictors read it; the atoms' source, the probe's layer and, with
    ``--token-model``, where the token distributions came from."""
    from vlaprobe.cognition.core import Cognition
    from vlaprobe.cognition.failure_scores import alarm_context, cognition_columns, run_cognition
    from vlaprobe.cognition.monitor_inputs import check_store
    from vlaprobe.cognition.plan import TaskGoal, stored_task_goal
    from vlaprobe.cognition.readout import HEADS, ProbeReadout
    from vlaprobe.collection.defined import only_defined
    from vlaprobe.collection.store import ActivationStore
    from vlaprobe.collection.verify import require_intact

    store = ActivationStore.open(cfg.store)
    infos = store.episodes()
    require_intact(cfg.store, read=True, keys=[e.key for e in infos])
    layer = store.num_hidden_states // 2 if cfg.layer is None else cfg.layer
    if not 0 <= layer < store.num_hidden_states:
        raise VlaprobeError(
            f"--layer {layer} is not a hidden state of {cfg.store} (0..{store.num_hidden_states - 1})"
        )
    readout = None if cfg.probes is None else ProbeReadout.load(cfg.probes, model_id=store.model_id)
    if readout is not None:  # its suite, observer and atoms, as `vlaprobe cognition` checks them
        check_store(store, readout, cfg.store)
    observer = None if cfg.token_model is None else token_observer(store, cfg.token_model)
    matched = total = 0
    cogs: dict[TaskGoal, Cognition] = {}
    data = []
    for info in infos:
        attrs = store.episode(info.key).attributes
        goal = stored_task_goal(store.suite, info.task, attrs, f"episode {info.key} of {cfg.store}")
        if goal not in cogs:
            probed = None if readout is None else readout.probed
            cogs[goal] = Cognition(
                store.atom_names["object"], store.atom_names["action"], goal, probed=probed
            )
        if readout is None:
            values: Mapping[str, np.ndarray] = {h: store.labels(h, [info.key]) for h in HEADS}
        else:
            values = readout.assign_steps(
                {h: store.layer(readout.layers[h], [info.key]) for h in HEADS}
            ).values
        values = only_defined(values, store.episode_defined(info.key))  # undefined atoms are never asserted
        steps = run_cognition(cogs[goal], values["object"], values["action"])
        cols, rules, subgoal = cognition_columns(steps)
        violated, last_event = alarm_context(steps)
        tokens = None
        if observer is not None:
            tokens, same = episode_tokens(observer, store.episode(info.key), cfg.store)
            matched, total = matched + same, total + len(tokens)
        data.append(
            EpisodeData(
                key=info.key,
                task=info.task,
                failed=not info.success,
                failure_step=attrs.failure_step,
                hidden=np.asarray(store.layer(layer, [info.key]), np.float32),
                progress=np.array([s.progress for s in steps]),
                cognition=cols,
                rules=rules,
                subgoal=subgoal,
                tokens=tokens,
                violated_atoms=violated,
                last_event=last_event,
            )
        )
    source = None
    if observer is not None:
        how = (
            f"recomputed with {cfg.token_model} from the stored images: entropy and top probability of the"
            " action-bin distribution of each of the 7 action tokens, averaged"
        )
        source = TokenSource(how, round(matched / max(total, 1), 4))
    return data, "truth" if cfg.probes is None else str(cfg.probes), layer, source
