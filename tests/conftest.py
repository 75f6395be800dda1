"""Fixtures shared by every test directory."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest


def schema_problems(path: Path) -> tuple[dict[str, str], list[str]]:
    """Open an MCAP recording with the ``mcap`` reader and validate every message against its
    channel's JSON Schema: ``({topic: schema name}, [problems])``; a channel without a schema,
    a non-JSON channel and an invalid message are problems."""
    import jsonschema
    from mcap.reader import make_reader

    problems: list[str] = []
    validators: dict[int, jsonschema.protocols.Validator] = {}
    names: dict[str, str] = {}
    with Path(path).open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, f"{path} has no summary"
        for ch in summary.channels.values():
            if ch.schema_id == 0 or ch.message_encoding != "json":
                problems.append(f"{ch.topic}: schema {ch.schema_id}, {ch.message_encoding}")
                continue
            schema = summary.schemas[ch.schema_id]
            names[ch.topic] = schema.name
            if schema.encoding != "jsonschema":
                problems.append(f"{ch.topic}: schema encoding {schema.encoding}")
                continue
            doc = json.loads(schema.data)
            jsonschema.Draft202012Validator.check_schema(doc)
            validators[ch.id] = jsonschema.Draft202012Validator(doc)
        for _schema, ch, msg in reader.iter_messages():
            v = validators.get(ch.id)
            if v is None:
                continue
            errors = list(v.iter_errors(json.loads(msg.data)))
            if errors:
                problems.append(f"{ch.topic}: {errors[0].message}")
    return names, problems


@pytest.fixture
def recording_schemas() -> Callable[[Path], tuple[dict[str, str], list[str]]]:
    """:func:`schema_problems`, for tests that check a recording opens in Foxglove."""
    return schema_problems
