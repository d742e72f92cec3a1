"""The message models: the exported schema is current, client frames parse or fail with a reason."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from vlaprobe.live import protocol as P


def test_schema_file_is_current() -> None:
    assert P.SCHEMA_FILE.read_text() == P.schema_text(), (
        "protocol.schema.json is stale: run python -m vlaprobe.live.protocol"
    )


def test_schema_names_every_message() -> None:
    defs = json.loads(P.SCHEMA_FILE.read_text())["$defs"]
    server = {"Hello", "EpisodeStart", "Step", "History", "EpisodeEnd", "ErrorMessage"}
    client = {"StartCommand", "StopCommand", "PauseCommand", "ResumeCommand", "DropCommand", "ReplayCommand"}
    assert server | client | {"EpisodeListItem", "EpisodeRecord"} <= set(defs)
    assert {"status", "step", "image"} <= set(defs["Step"]["properties"])  # the paper's client fields


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ('{"type":"start","task":3}', P.StartCommand),
        (
            '{"type":"start","task":"Pick up the bowl","init":2,"driver":"policy","max_steps":50}',
            P.StartCommand,
        ),
        ('{"type":"drop","steps":4}', P.DropCommand),
        ('{"type":"replay","episode_id":"store-t00_i00_a00","hz":5}', P.ReplayCommand),
        ('{"type":"stop"}', P.StopCommand),
    ],
)
def test_client_messages_parse(text: str, kind: type) -> None:
    assert isinstance(P.CLIENT.validate_json(text), kind)


@pytest.mark.parametrize(
    "text",
    [
        '{"type":"start"}',
        '{"type":"start","task":1,"driver":"human"}',
        '{"type":"start","task":1,"init":"some"}',
        '{"type":"drop","steps":0}',
        '{"type":"stop","now":true}',
        '{"type":"replay","episode_id":"x","hz":-1}',
        "[1,2]",
        "not json",
    ],
)
def test_bad_client_messages_fail(text: str) -> None:
    with pytest.raises(ValidationError):
        P.CLIENT.validate_json(text)
