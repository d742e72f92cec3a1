"""Trained probes on disk (safetensors + JSON, no pickle) and their use on live hidden states.

A probe folder holds ``probes.safetensors`` with, per head, ``<head>.weight`` (layers, hidden, atoms),
``<head>.bias`` (layers, atoms) and, when trained on standardized features, ``<head>.mean`` and
``<head>.std`` (layers, hidden); and ``probes.json`` with everything needed to use them: the observer
model and pooling they belong to, the probed hidden-state indices, each head's kept atoms (the weight
columns), dropped atoms with reasons, best layer and the metric that chose it, the layers tied with it and
the default layer (the earliest of them, read when no layer is given), threshold, the training configuration
and seeds (:class:`vlaprobe.probes.probemeta.ProbesMeta`).

    probes = ProbeSet.load("runs/default/probes", model_id=policy.model_id, pooling="last_prompt")
    atoms = probes.predict(hidden_states)          # (33, 4096) -> {"on(bowl,plate)": 1, ...} at default layers
    atoms = probes.predict(h, layer=12, head="object")   # one hidden state (4096,) from layer 12
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import write_atomic
from vlaprobe.probes.apply import apply_probes
from vlaprobe.probes.probemeta import (
    FORMAT,
    META_FILE,
    ProbesMeta,
    read_probes_meta,
    write_probes_meta,
)

WEIGHTS_FORMAT_VERSION = 1
"""Version of ``probes.safetensors`` (its tensor names and shapes), recorded in the file's metadata."""
WEIGHTS_FILE = "probes.safetensors"
__all__ = ["META_FILE", "WEIGHTS_FILE", "ProbeSet", "ProbesMeta"]


class ProbeSet:
    """The per-layer probes of every head of one observer model, ready for inference."""

    def __init__(
        self, meta: ProbesMeta, tensors: dict[str, torch.Tensor], where: str = "these probes"
    ) -> None:
        self.meta = meta
        """``probes.json``."""
        self.tensors = {k: v.float().contiguous() for k, v in tensors.items()}
        self.layers: list[int] = list(meta.layers)
        """Hidden-state index of each weight slice."""
        self.where = where
        """The folder the probes were loaded from, for messages."""

    # -- identity ---------------------------------------------------------------------------------
    @property
    def model_id(self) -> str:
        return self.meta.model_id

    @property
    def pooling(self) -> str:
        return self.meta.pooling

    @property
    def suite(self) -> str:
        """The LIBERO suite of the episodes the probes were trained on."""
        return self.meta.suite

    @property
    def threshold(self) -> float:
        return float(self.meta.threshold)

    @property
    def heads(self) -> list[str]:
        return list(self.meta.heads)

    def atoms(self, head: str) -> list[str]:
        """Kept atoms of ``head``: the probe outputs, in weight-column order."""
        return list(self.meta.heads[head].kept)

    def atom_names(self, head: str) -> list[str]:
        """Every atom of ``head`` in vocabulary order, probed or not (:meth:`atoms`: the probed ones)."""
        return list(self.meta.heads[head].atom_names or self.atoms(head))

    def dropped(self, head: str) -> dict[str, float]:
        """Atoms of ``head`` left unprobed (too rare or too common in training): atom -> training frequency."""
        return {d.atom: float(d.train_frequency) for d in self.meta.heads[head].dropped}

    @property
    def num_hidden_states(self) -> int:
        """Hidden states of the observer model (the probes may cover a subset: :attr:`layers`)."""
        return int(self.meta.num_hidden_states)

    @property
    def hidden_size(self) -> int:
        return int(self.meta.hidden_size)

    @property
    def refit_on_all(self) -> bool:
        """The probes were refit on every episode after evaluation (none of them is held out any more)."""
        return self.meta.trained_on.split.startswith("all")

    def best_layer(self, head: str) -> int:
        """Hidden-state index chosen for ``head`` (by its ``best_metric``)."""
        return int(self.meta.heads[head].best_layer)

    def tied_layers(self, head: str) -> list[int]:
        """Layers of ``head`` statistically tied with its best (the best included)."""
        return list(self.meta.heads[head].tied_layers)

    def default_layer(self, head: str) -> int:
        """The layer ``head`` is read at when none is given: the earliest layer tied with the best."""
        layer = self.meta.heads[head].default_layer
        return self.best_layer(head) if layer is None else int(layer)

    def check(
        self, model_id: str | None = None, pooling: str | None = None, suite: str | None = None
    ) -> None:
        """Raise VlaprobeError unless these probes were trained on ``model_id`` with ``pooling`` in ``suite``."""
        where = self.where
        if suite is not None and suite != self.suite:
            raise VlaprobeError(
                f"probes in {where} were trained on {self.suite} episodes, not {suite}; train probes on a "
                f"{suite} store (vlaprobe train) or use --suite {self.suite}"
            )
        if model_id is not None and model_id != self.model_id:
            raise VlaprobeError(
                f"probes in {where} were trained on model {self.model_id!r}, not {model_id!r}; "
                f"train probes on activations of {model_id!r} (vlaprobe train) or load that model"
            )
        if pooling is not None and pooling != self.pooling:
            raise VlaprobeError(
                f"probes in {where} were trained on {self.pooling!r} pooling, not {pooling!r}; "
                f"collect with --pooling {self.pooling} or train probes for {pooling!r}"
            )

    # -- disk -------------------------------------------------------------------------------------
    def save(self, folder: str | Path) -> Path:
        """Write ``probes.safetensors`` then ``probes.json`` (the JSON last: a folder with it is complete)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        write_atomic(
            folder / WEIGHTS_FILE,
            lambda tmp: save_file(
                self.tensors, tmp, metadata={"format": FORMAT, "format_version": str(WEIGHTS_FORMAT_VERSION)}
            ),
        )
        write_probes_meta(folder, self.meta)
        return folder

    @classmethod
    def load(
        cls,
        folder: str | Path,
        model_id: str | None = None,
        pooling: str | None = None,
        suite: str | None = None,
    ) -> ProbeSet:
        """Read a probe folder; refuse it (VlaprobeError) if it is not one or belongs to another model/pooling."""
        folder = Path(folder)
        meta_path, weights_path = folder / META_FILE, folder / WEIGHTS_FILE
        if not meta_path.is_file() or not weights_path.is_file():
            raise VlaprobeError(
                f"{folder} is not a probe folder (needs {META_FILE} and {WEIGHTS_FILE}); "
                "pass the folder written by vlaprobe train"
            )
        meta = read_probes_meta(folder)
        try:
            tensors = load_file(str(weights_path))
        except Exception as exc:  # any decoding failure means a damaged file
            raise VlaprobeError(f"cannot read {weights_path}: {exc}; run vlaprobe train again") from None
        probes = cls(meta, tensors, where=str(folder))
        for head in probes.heads:
            w = probes.tensors.get(f"{head}.weight")
            if w is None or tuple(w.shape) != (len(probes.layers), meta.hidden_size, len(probes.atoms(head))):
                raise VlaprobeError(
                    f"{weights_path} does not match {meta_path} for head {head!r}; "
                    "the folder is damaged, run vlaprobe train again"
                )
        probes.check(model_id, pooling, suite)
        return probes

    # -- inference --------------------------------------------------------------------------------
    def layer_logits(self, x: torch.Tensor, head: str, layer: int) -> torch.Tensor:
        """Logits (rows, atoms) of ``head``'s probe at hidden state ``layer`` for ``x`` (rows, hidden): the one
        place saved probes are applied (through :func:`vlaprobe.probes.apply.apply_probes`)."""
        if layer not in self.layers:
            raise VlaprobeError(f"no {head} probe for hidden state {layer}; these probes cover {self.layers}")
        i = self.layers.index(layer)
        t = self.tensors
        mean, std = t.get(f"{head}.mean"), t.get(f"{head}.std")
        return apply_probes(
            x[None],
            t[f"{head}.weight"][i : i + 1],
            t[f"{head}.bias"][i : i + 1],
            None if mean is None else mean[i : i + 1],
            None if std is None else std[i : i + 1],
        )[0]

    def logits(self, hidden: np.ndarray | torch.Tensor, head: str, layer: int | None = None) -> torch.Tensor:
        """Logits (atoms,) of ``head`` for one step.

        ``hidden`` is every hidden state of the step, (num_hidden_states, hidden) - the probe reads row
        ``layer`` - or the one hidden state at ``layer``, (hidden,). ``layer`` defaults to the head's
        :meth:`default_layer` (the earliest layer tied with the best). With "action_tokens" pooling an extra
        axis of 7 token positions before ``hidden`` is averaged, as in training.
        """
        x = torch.as_tensor(np.asarray(hidden) if not isinstance(hidden, torch.Tensor) else hidden).float()
        if self.pooling == "action_tokens" and x.ndim >= 2 and x.shape[-2] == 7:
            x = x.mean(-2)
        layer = self.default_layer(head) if layer is None else int(layer)
        if layer not in self.layers:
            raise VlaprobeError(f"no probe for hidden state {layer}; these probes cover {self.layers}")
        size = self.hidden_size
        if x.ndim == 2:
            if x.shape[0] != self.num_hidden_states or x.shape[1] != size:
                raise VlaprobeError(
                    f"hidden states of shape {tuple(x.shape)} do not fit these probes "
                    f"({self.num_hidden_states}, {size}); pass all hidden states of one step"
                )
            x = x[layer]
        elif x.ndim != 1 or x.shape[0] != size:
            raise VlaprobeError(
                f"a hidden state of shape {tuple(x.shape)} does not fit these probes (hidden size {size}); "
                f"pass ({size},) or ({self.num_hidden_states}, {size})"
            )
        return self.layer_logits(x[None], head, layer)[0]

    def probabilities(
        self, hidden: np.ndarray | torch.Tensor, layer: int | None = None, head: str | None = None
    ) -> dict[str, float]:
        """Atom -> probability for one step, every head (or ``head``), each at its default layer or ``layer``."""
        heads = [head] if head is not None else self.heads
        x = torch.as_tensor(np.asarray(hidden) if not isinstance(hidden, torch.Tensor) else hidden)
        single = x.ndim == 1 or (self.pooling == "action_tokens" and x.ndim == 2 and x.shape[0] == 7)
        if single and layer is None and len({self.default_layer(h) for h in heads}) > 1:
            raise VlaprobeError(
                "one hidden state fits one layer but the heads' default layers differ "
                f"({ {h: self.default_layer(h) for h in heads} }); pass layer= or head="
            )
        out: dict[str, float] = {}
        for h in heads:
            p = torch.sigmoid(self.logits(x, h, layer))
            out.update(zip(self.atoms(h), p.tolist(), strict=True))
        return out

    def predict(
        self, hidden: np.ndarray | torch.Tensor, layer: int | None = None, head: str | None = None
    ) -> dict[str, int]:
        """Atom -> 0/1 for one step (probability above the saved threshold); see :meth:`probabilities`."""
        return {a: int(p > self.threshold) for a, p in self.probabilities(hidden, layer, head).items()}
