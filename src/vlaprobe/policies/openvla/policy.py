"""``OpenVLAPolicy``: OpenVLA (official checkpoint or the tiny model) behind the ``VLAPolicy`` interface.

One ``step`` = LIBERO preprocessing of the raw frame → one prompt pass that yields every layer's hidden
states and the first action token → six KV-cached decode steps → OpenVLA's action decoding and LIBERO's
gripper convention.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from vlaprobe import devices
from vlaprobe.configs.policy import POOLINGS, Pooling, Preprocessing
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject
from vlaprobe.policies.base import PolicyStep
from vlaprobe.policies.openvla import actions, checkpoint, hub, preprocessing
from vlaprobe.policies.openvla.embedded import SEEDED_MODELS
from vlaprobe.policies.openvla.model import OpenVLA, Prediction, _pool
from vlaprobe.policies.openvla.tiny import LIBERO_SPATIAL_LIKE_STATS, tiny_config, tiny_state_dict
from vlaprobe.policies.openvla.tokenizer import HFTokenizer, Tokenizer, WordHashTokenizer, prompt_ids

BATCH = 32
"""Images per prompt pass in :meth:`OpenVLAPolicy.steps` (tiny-libero, 1 thread: 36 ms per image alone, ~16 ms
at 8-32; the pass holds every layer's states of the batch, so OpenVLA-7B's batches stay small in memory too)."""


def device_and_dtype(device: str) -> tuple[torch.device, torch.dtype]:
    """Device and dtype: CUDA runs bf16 (as OpenVLA's evaluation does), the CPU fp32."""
    dev = devices.resolve_device(device)
    return dev, (torch.bfloat16 if dev.type == "cuda" else torch.float32)


class OpenVLAPolicy:
    """An OpenVLA model run exactly as OpenVLA's LIBERO evaluation runs it, with hidden-state capture."""

    def __init__(
        self,
        model: OpenVLA,
        tokenizer: Tokenizer,
        norm_stats: JsonObject,
        *,
        model_id: str,
        pooling: Pooling = "last_prompt",
        unnorm_key: str | None = None,
        suite: str = "libero_spatial",
        center_crop: bool = True,
        preprocessing: Preprocessing = "numpy",
        source: str = "tiny",
        seed: int | None = None,
    ) -> None:
        if pooling not in POOLINGS:
            raise VlaprobeError(f"unknown pooling {pooling!r}; use one of {list(POOLINGS)}")
        self.model = model
        self.tokenizer = tokenizer
        self.norm_stats = norm_stats
        self.unnorm_key = actions.resolve_unnorm_key(norm_stats, unnorm_key, suite)
        self._q01, self._q99, self._mask = actions.action_stats(norm_stats, self.unnorm_key)
        self.model_id = model_id
        self.pooling: Pooling = pooling
        self.center_crop = center_crop
        self.preprocessing = preprocessing
        self.source = source
        self.seed = seed
        cfg = model.config
        self.num_hidden_states = cfg.num_hidden_states
        self.hidden_size = cfg.text.hidden_size
        param = next(model.parameters())
        self.device, self.dtype = param.device, param.dtype
        self._prompt_cache: dict[str, torch.Tensor] = {}

    # --- construction -----------------------------------------------------------------------------------

    @classmethod
    def tiny(cls, seed: int = 0, device: str = "auto", patch_size: int = 14, **kwargs: Any) -> OpenVLAPolicy:
        """The embedded random tiny model, built from ``seed`` (no file, no download); ``patch_size`` 28 gives
        the trained default's shape (64 patches) with random weights."""
        dev, dtype = device_and_dtype(device)
        cfg = tiny_config(patch_size=patch_size)
        shape = "" if patch_size == 14 else f"-p{patch_size}"
        model = checkpoint.build_model(cfg, tiny_state_dict(cfg, seed), dev, dtype)
        return cls(
            model,
            WordHashTokenizer(),
            LIBERO_SPATIAL_LIKE_STATS,
            model_id=f"tiny-openvla{shape}-seed{seed}",
            seed=seed,
            **kwargs,
        )

    @classmethod
    def from_folder(
        cls, folder: str | Path, device: str = "auto", model_id: str | None = None, **kwargs: Any
    ) -> OpenVLAPolicy:
        """An official OpenVLA checkpoint folder or one written by :meth:`save_pretrained` (``model_id``: the
        name to report, default the folder's recorded id or name)."""
        folder = Path(folder)
        cfg, norm_stats, block = checkpoint.read_config(folder)
        if block:
            if block.get("tokenizer") != WordHashTokenizer.name:
                raise VlaprobeError(
                    f"{folder} names unknown tokenizer {block.get('tokenizer')!r}; re-save it"
                )
            tokenizer: Tokenizer = WordHashTokenizer()
        else:
            tokenizer = HFTokenizer(folder)
        dev, dtype = device_and_dtype(device)
        model = checkpoint.build_model(cfg, checkpoint.read_state_dict(folder, dev, dtype), dev, dtype)
        return cls(
            model,
            tokenizer,
            norm_stats,
            model_id=model_id or block.get("model_id", folder.resolve().name),
            seed=block.get("seed"),
            source=str(folder),
            **kwargs,
        )

    @classmethod
    def load(cls, model: str, device: str = "auto", seed: int = 0, **kwargs: Any) -> OpenVLAPolicy:
        """``make_policy``'s implementation: a seeded name ("tiny", "tiny-libero-init"), a shipped model's name
        ("tiny-libero"), a checkpoint folder or a hub id (``openvla/openvla-7b-finetuned-libero-goal``: the
        snapshot in huggingface_hub's cache, :mod:`vlaprobe.policies.openvla.hub`)."""
        folder = hub.model_folder(model)
        if folder is None:
            return cls.tiny(seed=seed, device=device, patch_size=SEEDED_MODELS[model], **kwargs)
        return cls.from_folder(
            folder, device=device, model_id=model if hub.is_hub_id(model) else None, **kwargs
        )

    def save_pretrained(self, folder: str | Path) -> None:
        """Write this model (safetensors + JSON config) so ``make_policy(PolicyConfig(folder))`` rebuilds it exactly."""
        if not isinstance(self.tokenizer, WordHashTokenizer):
            raise VlaprobeError(
                "save_pretrained writes models with the built-in tokenizer; copy an official checkpoint folder instead"
            )
        extra = {"tokenizer": self.tokenizer.name, "model_id": self.model_id, "seed": self.seed}
        checkpoint.save_checkpoint(Path(folder), self.model, self.norm_stats, extra)

    # --- acting -----------------------------------------------------------------------------------------

    def prompt_ids(self, instruction: str) -> torch.Tensor:
        """(1, L) ids of the LIBERO prompt for ``instruction`` (cached per instruction)."""
        ids = self._prompt_cache.get(instruction)
        if ids is None:
            ids = torch.tensor(
                [prompt_ids(self.tokenizer, instruction)], dtype=torch.long, device=self.device
            )
            self._prompt_cache[instruction] = ids
        return ids

    def model_image(self, image: np.ndarray) -> np.ndarray:
        """The raw agentview render → the 224×224 uint8 image the model sees."""
        return preprocessing.libero_image(
            image, self.model.config.featurizer.image_size, self.center_crop, self.preprocessing
        )

    def pixel_values(self, model_image: np.ndarray) -> torch.Tensor:
        """(224, 224, 3) uint8 → (1, 6, 224, 224) on the model's device and dtype."""
        cfg = self.model.config
        pv = preprocessing.pixel_values(model_image, cfg.image_means, cfg.image_stds)
        return torch.from_numpy(pv)[None].to(self.device, self.dtype)

    def decode(self, token_ids: np.ndarray) -> np.ndarray:
        """``predict_action``'s action for these ids (before LIBERO's gripper post-processing)."""
        cfg = self.model.config
        return actions.decode_action(
            token_ids, self._q01, self._q99, self._mask, cfg.action_vocab_end, cfg.n_action_bins
        )

    def predict(
        self, model_image: np.ndarray, input_ids: torch.Tensor, pooling: Pooling | None
    ) -> Prediction:
        """The network's prediction for a preprocessed image and prompt ids."""
        return self.model.predict(self.pixel_values(model_image), input_ids, pooling=pooling)

    def step(self, image: np.ndarray, instruction: str) -> PolicyStep:
        return self.steps(self.model_image(image)[None], instruction)[0]

    def steps(self, model_images: np.ndarray, instruction: str) -> list[PolicyStep]:
        """:meth:`step` on preprocessed images (B, 224, 224, 3) uint8 under one instruction, in batches of
        :data:`BATCH` (one prompt pass and one decode per batch): for episodes whose driver does not read the
        model, observed after they ran (``vlaprobe.rollout.DeferredObserver``). One image runs exactly the
        operations of a single step; a batch rounds differently (tiny-libero: hidden states within ~1e-6)."""
        ids, out = self.prompt_ids(instruction), []
        for start in range(0, len(model_images), BATCH):
            chunk = model_images[start : start + BATCH]
            pixels = torch.cat([self.pixel_values(m) for m in chunk])
            for image, pred in zip(chunk, self.model.predict_batch(pixels, ids, self.pooling), strict=True):
                tokens = pred.action_token_ids.cpu().numpy().astype(np.int64)
                assert pred.hidden is not None
                out.append(
                    PolicyStep(
                        action=actions.libero_gripper(self.decode(tokens)),
                        hidden=pred.hidden.float().cpu().numpy(),
                        model_image=image,
                        action_tokens=tokens,
                    )
                )
        return out

    def token_uncertainty(self, model_images: np.ndarray, instruction: str) -> tuple[np.ndarray, np.ndarray]:
        """The action-token distribution of :meth:`steps` on preprocessed images (B, 224, 224, 3) uint8:
        ((B, 2) float64: the mean over the 7 tokens of the entropy (nats) and of the top probability of the
        softmax over the action bins, (B, 7) int64: the token ids the greedy decode chose, to check against
        the stored ``action_tokens``). For token-uncertainty failure scores of stored episodes."""
        cfg, ids = self.model.config, self.prompt_ids(instruction)
        end, out, tokens = cfg.action_vocab_end, [], []
        for start in range(0, len(model_images), BATCH):
            chunk = model_images[start : start + BATCH]
            pixels = torch.cat([self.pixel_values(m) for m in chunk])
            for pred in self.model.predict_batch(pixels, ids, None):
                logits = pred.step_logits[:, end - cfg.n_action_bins : end].double()
                logp = torch.log_softmax(logits, dim=-1)
                entropy = -(logp.exp() * logp).sum(-1).mean()
                top = logp.max(-1).values.exp().mean()
                out.append([float(entropy), float(top)])
                tokens.append(pred.action_token_ids.cpu().numpy().astype(np.int64))
        return np.array(out, np.float64).reshape(-1, 2), np.array(tokens, np.int64).reshape(-1, 7)

    def observe(self, model_images: np.ndarray, instruction: str) -> np.ndarray:
        """Hidden states of preprocessed images, (B, 224, 224, 3) uint8 → (B, layers, hidden) float32: the
        prompt pass of :meth:`step` batched, without decoding (re-observing stored episodes with another model,
        :mod:`vlaprobe.collection.reobserve`). The "action_tokens" pooling needs decoded tokens: use :meth:`step`."""
        if self.pooling == "action_tokens":
            raise VlaprobeError(
                'pooling "action_tokens" needs the decoded tokens; re-observe with last_prompt, mean_text or mean_all'
            )
        pixels = torch.cat([self.pixel_values(m) for m in model_images])
        ids = self.prompt_ids(instruction).expand(len(model_images), -1)
        with torch.inference_mode():
            out = self.model.language_model.model(
                inputs_embeds=self.model.embed(pixels, ids), use_cache=False, output_hidden_states=True
            )
            patches = self.model.config.num_patches
            rows = [
                _pool(tuple(h[i : i + 1] for h in out.hidden_states), self.pooling, patches)
                for i in range(len(model_images))
            ]
        return torch.stack(rows).float().cpu().numpy()

    def describe(self) -> JsonObject:
        return {
            "model_id": self.model_id,
            "family": "openvla",
            "source": self.source,
            "seed": self.seed,
            "num_hidden_states": self.num_hidden_states,
            "hidden_size": self.hidden_size,
            "pooling": self.pooling,
            "dtype": str(self.dtype).removeprefix("torch."),
            "device": str(self.device),
            "unnorm_key": self.unnorm_key,
            "center_crop": self.center_crop,
            "preprocessing": self.preprocessing,
            "tokenizer": self.tokenizer.name,
            "num_parameters": sum(p.numel() for p in self.model.parameters()),
            "architecture": self.model.config.to_dict(),
        }
