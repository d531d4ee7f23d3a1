"""The type registry: defaults as ROS fills them, both time styles, typedefs, CBOR and ROS 1 encodings."""

from __future__ import annotations

import struct

import cbor2
import pytest
from pydantic import ValidationError

from client_protocol.definitions import MESSAGES, SERVICES
from client_protocol.registry import TypeRegistry, describe_validation_error, normalize_type_name, parse_definition


@pytest.fixture(scope="module")
def registry() -> TypeRegistry:
    return TypeRegistry()


def test_every_definition_builds_a_model(registry):
    for name in MESSAGES:
        registry.model(name)()  # ROS defaults make every type constructible empty
    for name in SERVICES:
        request, response = registry.service_parts(name)
        registry.model(request)(), registry.model(response)()


@pytest.mark.parametrize("given,expected", [
    ("std_msgs/msg/String", "std_msgs/String"), ("std_srvs/srv/SetBool", "std_srvs/SetBool"),
    ("std_msgs/String", "std_msgs/String"), ("custom/action/Wave", "custom/Wave"),
])
def test_type_name_normalisation(given, expected):
    assert normalize_type_name(given) == expected


def test_parse_definition_resolves_names_arrays_and_constants():
    spec = parse_definition("pkg/Thing", "Header header  # comment\nuint8 ON=0\nPart[3] parts\nfloat32[] xs")
    assert [(f.name, f.type, f.array_len) for f in spec.fields] == [
        ("header", "std_msgs/Header", None), ("parts", "pkg/Part", 3), ("xs", "float32", 0)]
    assert [(c.name, c.value) for c in spec.constants] == [("ON", "0")]
    with pytest.raises(ValueError, match="cannot parse"):
        parse_definition("pkg/Bad", "float64")


def test_integer_ranges_and_strict_types(registry):
    with pytest.raises(ValidationError):
        registry.validate("sensor_msgs/Image", {"is_bigendian": 256})
    with pytest.raises(ValidationError):
        registry.validate("std_msgs/Bool", {"data": 1})
    with pytest.raises(ValidationError):
        registry.validate("std_msgs/Int32", {"data": 1.5})
    assert registry.validate("std_msgs/Float64", {"data": 2}).data == 2.0  # ints are fine for floats, as in ROS


def test_validation_messages_name_the_field(registry):
    with pytest.raises(ValidationError) as err:
        registry.validate("geometry_msgs/PoseStamped", {"pose": {"position": {"x": "left"}}})
    assert describe_validation_error(err.value, "msg") == \
        "'msg.pose.position.x': Input should be a valid number (got 'left')"


def test_typedefs_include_nested_types_and_constants(registry):
    typedefs = registry.typedefs("rosgraph_msgs/Log")
    assert typedefs[0]["constnames"] == ["DEBUG", "INFO", "WARN", "ERROR", "FATAL"]
    assert typedefs[0]["constvalues"][:2] == ["1", "2"]
    assert [t["type"] for t in typedefs] == ["rosgraph_msgs/Log", "std_msgs/Header"]


def test_cbor_typed_arrays_and_ros1_bytes(registry):
    joy = registry.validate("sensor_msgs/Joy", {"header": {"seq": 7, "stamp": {"secs": 1, "nsecs": 2}},
                                                "axes": [0.5, -1.0], "buttons": [1, 0, 1]})
    value = registry.to_cbor_value("sensor_msgs/Joy", joy)
    assert value["axes"] == cbor2.CBORTag(85, struct.pack("<2f", 0.5, -1.0))
    assert value["buttons"] == cbor2.CBORTag(78, struct.pack("<3i", 1, 0, 1))
    raw = registry.serialize_ros1("sensor_msgs/Joy", joy)
    assert raw == struct.pack("<III", 7, 1, 2) + struct.pack("<I", 0) + struct.pack("<I2f", 2, 0.5, -1.0) + \
        struct.pack("<I3i", 3, 1, 0, 1)
