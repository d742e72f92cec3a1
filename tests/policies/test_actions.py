"""Token → action decoding, LIBERO's gripper convention, tokenizers."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from vlaprobe.errors import VlaprobeError
from vlaprobe.policies.openvla import actions
from vlaprobe.policies.openvla.model import _official_action_ids
from vlaprobe.policies.openvla.tokenizer import (
    EMPTY_TOKEN_ID,
    HFTokenizer,
    WordHashTokenizer,
    libero_prompt,
    prompt_ids,
)

Q01 = np.array([-0.5, -1.0, 0.0, -0.1, -0.2, -0.3, 0.0])
Q99 = np.array([0.5, 1.0, 2.0, 0.1, 0.2, 0.3, 1.0])
MASK = np.array([True] * 6 + [False])


def test_bins():
    centers = actions.bin_centers(256)
    assert centers.shape == (255,)
    np.testing.assert_allclose(centers, -centers[::-1], atol=1e-15)
    assert centers[0] == pytest.approx(-1 + 1 / 255) and centers[-1] == pytest.approx(1 - 1 / 255)


@pytest.mark.parametrize(
    ("token", "normalized"),
    [
        (31744, 254 / 255),  # first action id: the top bin
        (31745, 254 / 255),  # bin index clipped at 254: the two highest ids share it
        (31872, 0.0),  # 32000 - 31872 - 1 = 127: the middle bin
        (31871, 2 / 255),
        (31999, -254 / 255),  # last action id: the bottom bin
        (32063, -254 / 255),  # padding ids clip to the bottom bin
        (1000, 254 / 255),  # text ids clip to the top bin
    ],
)
def test_known_tokens_decode_to_their_bin(token, normalized):
    got = actions.decode_action(np.full(7, token), Q01, Q99, MASK)
    np.testing.assert_allclose(
        got[:6], 0.5 * (normalized + 1) * (Q99[:6] - Q01[:6]) + Q01[:6], rtol=0, atol=1e-12
    )
    assert got[6] == pytest.approx(normalized, abs=1e-12)  # masked out: the gripper stays normalised


def test_libero_gripper_binarizes_then_inverts():
    raw = np.array([0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 0.97])
    out = actions.libero_gripper(raw)
    assert out[-1] == -1.0 and raw[-1] == 0.97  # 1 = open in the data → -1 = open for LIBERO; input untouched
    np.testing.assert_array_equal(out[:6], raw[:6])
    assert actions.libero_gripper(np.array([0.0] * 6 + [0.03]))[-1] == 1.0  # closing
    # a gripper left un-normalised (mask false) below 0 closes too
    assert actions.libero_gripper(np.array([0.0] * 6 + [-0.92]))[-1] == 1.0
    assert actions.libero_gripper(np.array([0.0] * 6 + [0.5]))[-1] == 0.0  # np.sign(0), exactly as OpenVLA


def test_unnorm_key_falls_back_to_no_noops():
    stats = {
        "libero_spatial_no_noops": {
            "action": {"q01": Q01.tolist(), "q99": Q99.tolist(), "mask": MASK.tolist()}
        }
    }
    assert actions.resolve_unnorm_key(stats, "libero_spatial") == "libero_spatial_no_noops"
    q01 = actions.action_stats(stats, "libero_spatial")[0]
    np.testing.assert_array_equal(q01, Q01)
    with pytest.raises(VlaprobeError, match="libero_goal"):
        actions.resolve_unnorm_key(stats, "libero_goal")
    assert actions.resolve_unnorm_key(stats, None, "libero_spatial") == "libero_spatial_no_noops"
    assert actions.resolve_unnorm_key(stats, None, "libero_goal") == "libero_spatial_no_noops"  # the only key
    two = {**stats, "libero_goal_no_noops": stats["libero_spatial_no_noops"]}
    assert actions.resolve_unnorm_key(two, None, "libero_goal") == "libero_goal_no_noops"  # the suite's
    with pytest.raises(VlaprobeError, match="libero_10"):
        actions.resolve_unnorm_key(two, None, "libero_10")  # two keys, neither the suite's
    no_mask = {"k": {"action": {"q01": [0.0, 0.0], "q99": [1.0, 2.0]}}}
    assert actions.action_stats(no_mask, "k")[2].tolist() == [True, True]
    with pytest.raises(VlaprobeError, match="malformed"):
        actions.action_stats({"k": {"action": {"q99": [1.0]}}}, "k")


def test_eos_makes_predict_action_reach_back_into_the_prompt():
    prompt = torch.arange(100, 110)
    generated = torch.tensor([31800, 31801, 2, 31803, 31804, 31805, 31806])
    assert (
        _official_action_ids(prompt, generated, eos=2).tolist()
        == [105, 106, 107, 108, 109, 31800, 31801, 2][-7:]
    )
    assert (
        _official_action_ids(prompt, generated[[0, 1, 3, 4, 5, 6, 0]], eos=2).tolist()
        == generated[[0, 1, 3, 4, 5, 6, 0]].tolist()
    )


def test_prompt_format():
    assert (
        libero_prompt("Put the Bowl on the Plate")
        == "In: What action should the robot take to put the bowl on the plate?\nOut:"
    )


def test_word_hash_tokenizer():
    tok = WordHashTokenizer()
    ids = prompt_ids(tok, "Pick up the black bowl")
    assert ids[0] == 1 and ids[-1] == EMPTY_TOKEN_ID and EMPTY_TOKEN_ID not in ids[:-1]
    assert all(3 <= i < 31744 for i in ids[1:-1])  # the action ids stay reserved
    assert ids == prompt_ids(WordHashTokenizer(), "pick up the black bowl")  # deterministic, lower-cased
    words = tok.encode("the the bowl plate")[1:]
    assert words[0] == words[1] and len(set(words)) == 3
    assert len(ids) == len(tok.encode(libero_prompt("pick up the black bowl"))) + 1


def test_hf_tokenizer_reads_tokenizer_json(tmp_path):
    from tokenizers import Regex, Tokenizer, pre_tokenizers
    from tokenizers.models import WordLevel

    vocab = {
        "<unk>": 0,
        "<s>": 1,
        "</s>": 2,
        "In": 10,
        ":": 11,
        "Out": 12,
        "?": 13,
        "go": 14,
        "\n": 15,
        " ": 16,
    }
    tok = Tokenizer(WordLevel(vocab, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.Split(Regex(r"\w+|[^\w\s]|\n"), behavior="isolated")
    tok.save(str(tmp_path / "tokenizer.json"))
    (tmp_path / "tokenizer_config.json").write_text(json.dumps({"bos_token": {"content": "<s>"}}))
    hf = HFTokenizer(tmp_path)
    assert hf.encode("In: go?\nOut:")[:2] == [1, 10]
    ids = prompt_ids(hf, "GO")
    assert ids[0] == 1 and ids[-1] == EMPTY_TOKEN_ID and 14 in ids and ids[-2] == 11


def test_hf_tokenizer_missing_is_one_line_error(tmp_path):
    with pytest.raises(VlaprobeError, match=r"tokenizer\.json") as err:
        HFTokenizer(tmp_path)
    assert "\n" not in str(err.value)
    (tmp_path / "tokenizer.json").write_text("{not json")
    with pytest.raises(VlaprobeError, match="cannot read"):
        HFTokenizer(tmp_path)
