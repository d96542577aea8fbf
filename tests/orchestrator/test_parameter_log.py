"""A unit's parameter message never carries NaN or infinity as JSON null."""
from __future__ import annotations

import json

from mcap.reader import make_reader

from immersim.orchestrator.fmu import VarInfo
from immersim.orchestrator.observers import McapObserver, write_parameters


def _param(name, type_="Real"):
    return VarInfo(name, 0, type_, "parameter", "fixed", "m", None, f"parameter {name}")


def test_non_finite_parameters_are_logged_as_strings_not_null(tmp_path):
    path = tmp_path / "p.mcap"
    obs = McapObserver(path)
    infos = [_param("a"), _param("b"), _param("c"), _param("d"), _param("n", "Integer")]
    write_parameters(obs, "u", infos, [1.5, float("nan"), float("inf"), float("-inf"), 3], 0)
    obs.close()
    with open(path, "rb") as f:
        (schema, channel, message), = list(make_reader(f).iter_messages())
    assert b"null" not in message.data
    assert json.loads(message.data) == {"a": 1.5, "b": "NaN", "c": "Infinity", "d": "-Infinity", "n": 3}
    props = json.loads(schema.data)["properties"]
    assert [props[k]["type"] for k in "abcdn"] == ["number", "string", "string", "string", "integer"]
    assert props["b"]["unit"] == "m" and props["b"]["description"] == "parameter b"
