"""Prompt → token ids, for real checkpoints (Llama's tokenizer) and for the tiny model (no download).

OpenVLA's LIBERO prompt is ``In: What action should the robot take to {instruction.lower()}?\\nOut:``,
tokenised with <s> (id 1) first. ``predict_action`` then appends the empty token 29871 ("▁") when the ids
do not already end with it, matching what the model saw in training; :func:`prompt_ids` does the same.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Protocol

from vlaprobe.errors import VlaprobeError

BOS_ID = 1
EMPTY_TOKEN_ID = 29871
"""Llama's "▁" (a lone word-start marker) that OpenVLA appends after "Out:"."""
ACTION_ID_RANGE = (31744, 32000)
"""The 256 ids OpenVLA re-purposed as action bins (the last 256 of Llama's 32000)."""


def libero_prompt(instruction: str) -> str:
    """OpenVLA's prompt for an instruction (lower-cased, as the LIBERO eval does)."""
    return f"In: What action should the robot take to {instruction.lower()}?\nOut:"


class Tokenizer(Protocol):
    name: str

    def encode(self, text: str) -> list[int]:
        """Token ids of ``text`` with <s> first."""
        ...


def prompt_ids(tokenizer: Tokenizer, instruction: str) -> list[int]:
    """Ids of the LIBERO prompt, ending with the empty token as ``predict_action`` feeds them."""
    ids = tokenizer.encode(libero_prompt(instruction))
    return ids if ids[-1] == EMPTY_TOKEN_ID else [*ids, EMPTY_TOKEN_ID]


class WordHashTokenizer:
    """The tiny model's tokenizer: words and punctuation hashed (BLAKE2b, stable across processes) into
    the text ids 3 … 31743, skipping 29871; ids 0–2 keep Llama's <unk>/<s>/</s> roles and 31744 … 31999
    stay reserved for action bins, so the tiny model has OpenVLA's id layout."""

    name = "word-hash-v1"
    _pattern = re.compile(r"\w+|[^\w\s]|\n")

    def encode(self, text: str) -> list[int]:
        ids = [BOS_ID]
        span = ACTION_ID_RANGE[0] - 3 - 1  # 3 … 31743 without 29871
        for piece in self._pattern.findall(text):
            h = int.from_bytes(hashlib.blake2b(piece.encode(), digest_size=8).digest(), "little")
            i = 3 + h % span
            ids.append(i + 1 if i >= EMPTY_TOKEN_ID else i)
        return ids


class HFTokenizer:
    """Llama's tokenizer from a checkpoint folder's ``tokenizer.json`` (the ``tokenizers`` engine behind
    transformers' ``LlamaTokenizerFast``), or its ``tokenizer.model`` through transformers."""

    def __init__(self, folder: Path) -> None:
        self.name = f"hf:{folder.name}"
        self._bos = BOS_ID
        config = folder / "tokenizer_config.json"
        if config.is_file():
            try:
                bos = json.loads(config.read_text()).get("bos_token")
            except json.JSONDecodeError:
                raise VlaprobeError(f"cannot parse {config}; restore it from the checkpoint") from None
            self._bos_text = bos.get("content") if isinstance(bos, dict) else bos
        else:
            self._bos_text = None
        if (folder / "tokenizer.json").is_file():
            from tokenizers import Tokenizer as RustTokenizer

            try:
                self._tok = RustTokenizer.from_file(str(folder / "tokenizer.json"))
            except Exception as exc:  # any parse error is the same user error
                raise VlaprobeError(
                    f"cannot read {folder / 'tokenizer.json'}: {exc}; restore it from the checkpoint"
                ) from None
            self._encode = lambda text: self._tok.encode(text, add_special_tokens=False).ids
            bos = None if self._bos_text is None else self._tok.token_to_id(self._bos_text)
            if bos is not None:
                self._bos = bos
        elif (folder / "tokenizer.model").is_file():
            try:
                from transformers import AutoTokenizer

                tok = AutoTokenizer.from_pretrained(str(folder))
            except Exception as exc:  # sentencepiece or protobuf missing, or a bad file
                raise VlaprobeError(
                    f"cannot load {folder / 'tokenizer.model'} ({type(exc).__name__}); add the checkpoint's "
                    "tokenizer.json or pip install sentencepiece"
                ) from None
            self._encode = lambda text: tok(text, add_special_tokens=False)["input_ids"]
            self._bos = tok.bos_token_id if tok.bos_token_id is not None else BOS_ID
        else:
            raise VlaprobeError(
                f"no tokenizer.json or tokenizer.model in {folder}; copy them from the base OpenVLA checkpoint"
            )

    def encode(self, text: str) -> list[int]:
        return [self._bos, *self._encode(text)]
