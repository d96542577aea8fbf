"""FMI 3.0 Binary values in the "ros1" log encoding: ``uint8[]`` fields as ROS 1 serialises them
(a little-endian uint32 length, then the bytes), wherever they sit among fixed-size fields."""
import struct

import pytest

from immersim.orchestrator.fmu import VarInfo
from immersim.orchestrator.observers import json_schema, ros1_definition, ros1_struct


def _schema(types):
    return json_schema("u", [VarInfo(f"v{i}", i, t, "output", "discrete", "", None, "") for i, t in enumerate(types)])


@pytest.mark.parametrize("types,values", [
    (["Binary"], [b""]),
    (["Binary", "Float64", "Binary"], [b"\x00\x01", -2.5, b"abc"]),
    (["Int8", "Binary", "Binary", "UInt64", "Boolean"], [-3, b"\xff" * 300, b"", 2**64 - 1, True]),
])
def test_binary_packs_as_ros1_uint8_arrays(types, values):
    """The packing is the concatenation, field by field, of ``struct`` codes for fixed-size
    fields and length-prefixed bytes for each Binary; unpacking gives the values back."""
    schema = _schema(types)
    packer = ros1_struct(schema)
    codes = {"Float64": "<d", "Int8": "<b", "UInt64": "<Q", "Boolean": "<?"}
    expected = b"".join(struct.pack("<I", len(v)) + v if t == "Binary" else struct.pack(codes[t], v)
                        for t, v in zip(types, values))
    assert packer.pack(*values) == expected
    assert packer.unpack(expected) == tuple(values)
    assert [line.split()[0] for line in ros1_definition(schema).splitlines()] == \
        ["uint8[]" if t == "Binary" else {"Float64": "float64", "Int8": "int8", "UInt64": "uint64",
                                          "Boolean": "bool"}[t] for t in types]


def test_a_channel_without_binary_keeps_its_fixed_struct_and_a_string_keeps_json():
    assert isinstance(ros1_struct(_schema(["Float64", "Int32"])), struct.Struct)
    assert ros1_struct(_schema(["Binary", "String"])) is None


def test_a_binary_value_that_is_not_bytes_is_refused():
    with pytest.raises(TypeError):
        ros1_struct(_schema(["Binary"])).pack("text")
