"""Read and write OpenVLA checkpoint folders by the official parameter names (no ``trust_remote_code``).

A folder holds ``config.json`` (official ``OpenVLAConfig`` fields), ``model.safetensors`` or shards with
``model.safetensors.index.json``, and the action statistics (``dataset_statistics.json``, which OpenVLA's
LIBERO eval prefers, else ``norm_stats`` inside config.json). Folders written by vlaprobe add a
``"vlaprobe"`` block to config.json with the full architecture (the shrunk ViT dims of a tiny model, which
official config fields cannot express) and the tokenizer to use. A test checkpoint with shrunk ViTs may
instead carry the reference ``tiny_dims.json`` (``featurizers.{featurizer,fused_featurizer}`` dims).
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from vlaprobe.errors import VlaprobeError
from vlaprobe.files import Json, JsonObject, write_atomic
from vlaprobe.policies.openvla.config import OpenVLAConfig, from_official, to_official
from vlaprobe.policies.openvla.model import OpenVLA

FORMAT_VERSION = 1
"""Version of the ``"vlaprobe"`` block in config.json."""


def _read_json(path: Path) -> Json:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise VlaprobeError(f"cannot read {path} ({exc}); restore the checkpoint's copy") from None


def _tiny_dims_overrides(path: Path) -> dict[str, JsonObject]:
    dims = _read_json(path)
    try:
        out = {}
        for name in ("featurizer", "fused_featurizer"):
            d = dims["featurizers"][name]
            out[name] = {
                "embed_dim": int(d["embed_dim"]),
                "depth": int(d["depth"]),
                "num_heads": int(d["num_heads"]),
                "mlp_hidden": int(d["mlp_hidden_features"]),
            }
        return out
    except (KeyError, TypeError, ValueError):
        raise VlaprobeError(
            f"{path} lacks featurizers.*.{{embed_dim,depth,num_heads,mlp_hidden_features}}; fix it"
        ) from None


def read_config(folder: Path) -> tuple[OpenVLAConfig, JsonObject, JsonObject]:
    """(architecture, norm_stats, vlaprobe block or {}) of a checkpoint folder."""
    if not folder.is_dir():
        what = "is a file, not a folder" if folder.exists() else "not found"
        raise VlaprobeError(f"checkpoint folder {folder} {what}; pass 'tiny' or an OpenVLA checkpoint folder")
    if not (folder / "config.json").is_file():
        raise VlaprobeError(f"no config.json in {folder}; pass an OpenVLA checkpoint folder (HF layout)")
    raw = _read_json(folder / "config.json")
    if not isinstance(raw, dict) or raw.get("model_type") != "openvla":
        raise VlaprobeError(
            f"{folder / 'config.json'} is not an OpenVLA config (model_type must be 'openvla')"
        )
    block = raw.get("vlaprobe") or {}
    try:
        if block:
            if block.get("format_version") != FORMAT_VERSION:
                raise VlaprobeError(
                    f"{folder} was written by another vlaprobe format ({block.get('format_version')}); re-save it"
                )
            cfg = OpenVLAConfig.from_dict(block["architecture"])
        else:
            overrides = (
                _tiny_dims_overrides(folder / "tiny_dims.json")
                if (folder / "tiny_dims.json").is_file()
                else None
            )
            cfg = from_official(raw, overrides)
    except (KeyError, TypeError, ValueError) as exc:
        raise VlaprobeError(
            f"malformed {folder / 'config.json'} ({type(exc).__name__}: {exc}); restore it"
        ) from None
    stats_file = folder / "dataset_statistics.json"
    norm_stats = _read_json(stats_file) if stats_file.is_file() else raw.get("norm_stats")
    if not isinstance(norm_stats, dict) or not norm_stats:
        raise VlaprobeError(
            f"no action statistics in {folder}; add dataset_statistics.json from the fine-tune"
        )
    return cfg, norm_stats, block


def _weight_files(folder: Path) -> list[Path]:
    index = folder / "model.safetensors.index.json"
    if index.is_file():
        weight_map = _read_json(index).get("weight_map")
        if not isinstance(weight_map, dict):
            raise VlaprobeError(f"{index} has no weight_map; restore it from the checkpoint")
        files = sorted({folder / name for name in weight_map.values()})
    elif (folder / "model.safetensors").is_file():
        files = [folder / "model.safetensors"]
    else:
        files = sorted(folder.glob("*.safetensors"))
    if not files:
        raise VlaprobeError(f"no *.safetensors weights in {folder}; download the checkpoint's model shards")
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise VlaprobeError(
            f"weight shard(s) {missing} missing from {folder}; finish downloading the checkpoint"
        )
    return files


def read_state_dict(folder: Path, device: torch.device, dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """All tensors of the folder's safetensors files, cast to ``dtype`` on ``device``."""
    from safetensors import SafetensorError, safe_open

    tensors: dict[str, torch.Tensor] = {}
    for path in _weight_files(folder):
        try:
            with safe_open(str(path), framework="pt", device=str(device)) as f:
                for key in f.keys():  # noqa: SIM118 - safe_open is not a dict
                    # A copy owns freshly allocated (aligned) memory: kernels on unaligned views of
                    # the file buffer take other code paths and round differently.
                    tensors[key] = f.get_tensor(key).to(dtype=dtype, copy=True)
        except (SafetensorError, OSError) as exc:
            raise VlaprobeError(f"cannot read weights {path} ({exc}); re-download the file") from None
    return tensors


def _rope_inv_freq(cfg: OpenVLAConfig, device: torch.device) -> torch.Tensor:
    t = cfg.text
    dim = t.hidden_size // t.num_attention_heads
    return 1.0 / (t.rope_theta ** (torch.arange(0, dim, 2, dtype=torch.int64, device=device).float() / dim))


def build_model(
    cfg: OpenVLAConfig, state_dict: dict[str, torch.Tensor], device: torch.device, dtype: torch.dtype
) -> OpenVLA:
    """Instantiate the network on the meta device and adopt ``state_dict`` (no random init, no copies).

    Every name and shape must match: missing, unexpected or mis-shaped tensors are a one-line error.
    """
    with torch.device("meta"):
        model = OpenVLA(cfg)
    expected = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    missing = sorted(set(expected) - set(state_dict))
    unexpected = sorted(set(state_dict) - set(expected))
    if missing or unexpected:
        raise VlaprobeError(
            f"checkpoint does not match the OpenVLA layout: {len(missing)} missing (e.g. {missing[:2]}), "
            f"{len(unexpected)} unexpected (e.g. {unexpected[:2]}); pass an official OpenVLA checkpoint"
        )
    for key, shape in expected.items():
        if tuple(state_dict[key].shape) != shape:
            raise VlaprobeError(
                f"checkpoint tensor {key} has shape {list(state_dict[key].shape)} but config.json implies "
                f"{list(shape)}; config.json does not belong to these weights"
            )
    model.load_state_dict({k: v.to(device=device, dtype=dtype) for k, v in state_dict.items()}, assign=True)
    for name, buf in list(model.named_buffers()):
        if buf.is_meta:  # non-persistent RoPE frequencies: recomputed in float32 as transformers does
            if not name.endswith("inv_freq"):
                raise RuntimeError(f"unexpected non-persistent buffer {name}")
            owner = model.get_submodule(name.rsplit(".", 1)[0])
            setattr(owner, name.rsplit(".", 1)[1], _rope_inv_freq(cfg, device))
    return model.eval()


def save_checkpoint(
    folder: Path,
    model: OpenVLA,
    norm_stats: JsonObject,
    extra: JsonObject,
    state: dict[str, torch.Tensor] | None = None,
) -> None:
    """Write ``config.json`` (official fields + "vlaprobe" block) and ``model.safetensors`` (float32): the
    model's own weights, or ``state`` (same names and shapes, e.g. LoRA-merged weights) when given."""
    from safetensors.torch import save_file

    folder.mkdir(parents=True, exist_ok=True)
    if state is None:
        state = model.state_dict()
    state = {k: v.detach().to("cpu", torch.float32).contiguous() for k, v in state.items()}
    config = to_official(model.config, norm_stats)
    config["vlaprobe"] = {"format_version": FORMAT_VERSION, "architecture": model.config.to_dict(), **extra}
    write_atomic(folder / "model.safetensors", lambda p: save_file(state, p, metadata={"format": "pt"}))
    write_atomic(folder / "config.json", json.dumps(config, indent=2) + "\n")
