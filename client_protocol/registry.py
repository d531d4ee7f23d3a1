"""Turns ROS type definitions into pydantic models, rosapi TypeDefs, CBOR values and ROS 1 bytes.

One registry per server: its time style ("ros1" sends `{secs, nsecs}`, "ros2" sends `{sec, nanosec}`; both are
accepted on input) is fixed when it is built, so serialising a message costs no per-message switch.
"""

from __future__ import annotations

import array
import base64
import binascii
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal

import cbor2
from simclock import WALL, Clock
from pydantic_core import SchemaSerializer, SchemaValidator
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainSerializer,
    StrictBool,
    WithJsonSchema,
    StrictInt,
    StrictStr,
    ValidationError,
    create_model,
    model_validator,
)

from .definitions import MESSAGES, SERVICES

TimeStyle = Literal["ros1", "ros2"]

# ROS primitive -> (struct code for ROS 1 serialisation, integer bounds or None)
_INT_TYPES: dict[str, tuple[str, int, int]] = {
    "int8": ("b", -(2**7), 2**7 - 1),
    "byte": ("b", -(2**7), 2**7 - 1),
    "uint8": ("B", 0, 2**8 - 1),
    "char": ("B", 0, 2**8 - 1),
    "int16": ("h", -(2**15), 2**15 - 1),
    "uint16": ("H", 0, 2**16 - 1),
    "int32": ("i", -(2**31), 2**31 - 1),
    "uint32": ("I", 0, 2**32 - 1),
    "int64": ("q", -(2**63), 2**63 - 1),
    "uint64": ("Q", 0, 2**64 - 1),
}
_FLOAT_TYPES = {"float32": "f", "float64": "d"}
_TIME_TYPES = ("time", "duration")
PRIMITIVES = frozenset(_INT_TYPES) | frozenset(_FLOAT_TYPES) | {"bool", "string"} | set(_TIME_TYPES)
# uint8[] and char[] travel as base64 in JSON and as a byte string in CBOR (rosbridge's convention).
_BYTE_ARRAY_TYPES = ("uint8", "char")
# Typed-array tags of RFC 8746 (little-endian), as rosbridge packs numeric arrays for CBOR subscribers.
_CBOR_TYPED_ARRAY_TAGS: dict[str, tuple[int, str]] = {
    "int8": (72, "b"), "byte": (72, "b"), "int16": (77, "h"), "uint16": (69, "H"), "int32": (78, "i"),
    "uint32": (70, "I"), "int64": (79, "q"), "uint64": (71, "Q"), "float32": (85, "f"), "float64": (86, "d"),
}

_FIELD_RE = re.compile(r"^(?P<type>[A-Za-z][\w/]*)(?P<array>\[(?P<len>\d*)\])?\s+(?P<name>\w+)\s*(?:=\s*(?P<const>.*))?$")


def normalize_type_name(name: str) -> str:
    """`pkg/msg/Type`, `pkg/srv/Type` and `pkg/action/Type` are ROS 2 spellings of ROS 1's `pkg/Type`."""
    parts = name.strip().split("/")
    if len(parts) == 3 and parts[1] in ("msg", "srv", "action"):
        return f"{parts[0]}/{parts[2]}"
    return name.strip()


@dataclass(frozen=True)
class FieldSpec:
    name: str
    type: str  # a primitive, or a full `pkg/Type`
    array_len: int | None  # None: not an array; 0: variable length; N: fixed length N

    @property
    def is_byte_array(self) -> bool:
        return self.array_len is not None and self.type in _BYTE_ARRAY_TYPES

    @property
    def ros_type(self) -> str:
        """The field's type as a .msg file spells it (rosapi's `fieldtypes`)."""
        return self.type


@dataclass(frozen=True)
class ConstantSpec:
    name: str
    type: str
    value: str


@dataclass(frozen=True)
class MessageSpec:
    name: str
    fields: tuple[FieldSpec, ...]
    constants: tuple[ConstantSpec, ...]


def parse_definition(name: str, text: str) -> MessageSpec:
    """Parses one `.msg` body. Bare type names resolve to the message's own package (`Header` to std_msgs)."""
    package = name.split("/")[0]
    fields: list[FieldSpec] = []
    constants: list[ConstantSpec] = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        match = _FIELD_RE.match(line)
        if match is None:
            raise ValueError(f"{name}: cannot parse the line {raw!r}")
        ftype = match["type"]
        if ftype not in PRIMITIVES:
            if ftype == "Header":
                ftype = "std_msgs/Header"
            elif "/" not in ftype:
                ftype = f"{package}/{ftype}"
            ftype = normalize_type_name(ftype)
        if match["const"] is not None:
            constants.append(ConstantSpec(match["name"], ftype, match["const"].strip()))
            continue
        array_len = None if match["array"] is None else int(match["len"] or 0)
        fields.append(FieldSpec(match["name"], ftype, array_len))
    return MessageSpec(name, tuple(fields), tuple(constants))


def _bytes_from_wire(value: Any) -> Any:
    """uint8[] arrives as base64 text (rosbridge's encoding) or as a list of numbers (also allowed)."""
    if isinstance(value, str):
        try:
            return base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError) as exc:
            raise ValueError(f"not valid base64 ({exc})") from None
    if isinstance(value, list):
        if not all(isinstance(b, int) and not isinstance(b, bool) and 0 <= b <= 255 for b in value):
            raise ValueError("a byte array given as a list must hold integers 0..255")
        return bytes(value)
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value)
    raise ValueError("expected base64 text or a list of integers 0..255")


ByteArray = Annotated[
    bytes,
    BeforeValidator(_bytes_from_wire),
    PlainSerializer(lambda b: base64.b64encode(b).decode("ascii"), return_type=str, when_used="json"),
    WithJsonSchema({"type": "string", "contentEncoding": "base64",
                    "description": "uint8[] as base64 text; a list of integers 0..255 is accepted on input"}),
]

_MODEL_CONFIG = ConfigDict(strict=True, extra="forbid", populate_by_name=True)


_TIME_KEYS = frozenset(("secs", "nsecs", "sec", "nanosec"))


def _make_time_model(kind: str, style: TimeStyle) -> type[BaseModel]:
    """ROS time: `{secs, nsecs}` (ROS 1) or `{sec, nanosec}` (ROS 2) on input; the registry's style on output."""
    lower = 0 if kind == "time" else -(2**31)
    sec_alias, nsec_alias = ("sec", "nanosec") if style == "ros2" else ("secs", "nsecs")

    class _Time(BaseModel):
        model_config = _MODEL_CONFIG
        # the ROS 2 spelling of each field, which PlainCodec reads without calling _accept_both_styles
        ROS2_NAMES: ClassVar[dict[str, str]] = {"secs": "sec", "nsecs": "nanosec"}
        secs: Annotated[StrictInt, Field(ge=lower, le=2**32 - 1, serialization_alias=sec_alias)] = 0
        nsecs: Annotated[StrictInt, Field(ge=0, le=999_999_999, serialization_alias=nsec_alias)] = 0

        @model_validator(mode="before")
        @classmethod
        def _accept_both_styles(cls, data: Any) -> Any:
            if isinstance(data, dict) and data and not _TIME_KEYS.intersection(data):
                raise ValueError(f"a time is {{secs, nsecs}} (ROS 1) or {{sec, nanosec}} (ROS 2), not "
                                 f"{{{', '.join(sorted(map(str, data))[:4])}}}")
            if isinstance(data, dict) and ("sec" in data or "nanosec" in data):
                data = dict(data)
                if "sec" in data:
                    data["secs"] = data.pop("sec")
                if "nanosec" in data:
                    data["nsecs"] = data.pop("nanosec")
            return data

    _Time.__name__ = _Time.__qualname__ = "Time" if kind == "time" else "Duration"
    return _Time


class TypeRegistry:
    """Every known type's spec and model, plus the rules for unknown (opaque) types."""

    def __init__(
        self,
        messages: dict[str, str] = MESSAGES,
        services: dict[str, str] = SERVICES,
        time_style: TimeStyle = "ros1",
        clock: Clock = WALL,
    ) -> None:
        self.time_style = time_style
        self.clock = clock  # the server's: every header it stamps is on it (simulated in a `--speed max` replay)
        self._specs: dict[str, MessageSpec] = {}
        for name, text in messages.items():
            self._specs[normalize_type_name(name)] = parse_definition(name, text)
        self._services: dict[str, tuple[str, str]] = {}
        for name, text in services.items():
            name = normalize_type_name(name)
            request, _, response = text.partition("---")
            self._specs[f"{name}Request"] = parse_definition(f"{name}Request", request)
            self._specs[f"{name}Response"] = parse_definition(f"{name}Response", response)
            self._services[name] = (f"{name}Request", f"{name}Response")
        self._time_models = {kind: _make_time_model(kind, time_style) for kind in _TIME_TYPES}
        self._models: dict[str, type[BaseModel]] = {}
        self._codecs: dict[str, PlainCodec] = {}
        for spec in self._specs.values():  # resolve every reference now: a typo in a definition fails at start-up
            self.model(spec.name)

    # ---- look-ups -------------------------------------------------------------------------------------------
    def is_known_message(self, name: str) -> bool:
        name = normalize_type_name(name)
        return name in self._specs and name not in self._service_parts()

    def is_known_service(self, name: str) -> bool:
        return normalize_type_name(name) in self._services

    def _service_parts(self) -> set[str]:
        return {part for pair in self._services.values() for part in pair}

    def message_names(self) -> list[str]:
        parts = self._service_parts()
        return sorted(n for n in self._specs if n not in parts)

    def service_names(self) -> list[str]:
        return sorted(self._services)

    def spec(self, name: str) -> MessageSpec:
        return self._specs[normalize_type_name(name)]

    def service_parts(self, name: str) -> tuple[str, str]:
        """The request and response type names of a known service."""
        return self._services[normalize_type_name(name)]

    # ---- pydantic models ------------------------------------------------------------------------------------
    def model(self, name: str) -> type[BaseModel]:
        name = normalize_type_name(name)
        model = self._models.get(name)
        if model is None:
            spec = self._specs[name]
            fields: dict[str, Any] = {}
            for f in spec.fields:
                fields[f.name] = self._field_definition(name, f)
            model = create_model(name.replace("/", "__"), __config__=_MODEL_CONFIG, **fields)
            model.__doc__ = f"ROS type {name}"
            self._models[name] = model
        return model

    def _element_annotation(self, owner: str, ftype: str) -> Any:
        if ftype in _INT_TYPES:
            _, lo, hi = _INT_TYPES[ftype]
            return Annotated[StrictInt, Field(ge=lo, le=hi)]
        if ftype in _FLOAT_TYPES:
            return float
        if ftype == "bool":
            return StrictBool
        if ftype == "string":
            return StrictStr
        if ftype in _TIME_TYPES:
            return self._time_models[ftype]
        if ftype not in self._specs:
            raise ValueError(f"{owner}: refers to {ftype}, which is not defined")
        return self.model(ftype)

    def _field_definition(self, owner: str, f: FieldSpec) -> tuple[Any, Any]:
        if f.is_byte_array:
            if f.array_len:
                return (Annotated[ByteArray, Field(min_length=f.array_len, max_length=f.array_len)],
                        bytes(f.array_len))
            return (ByteArray, b"")
        element = self._element_annotation(owner, f.type)
        if f.array_len is None:
            return (element, self._default_factory(owner, f))
        if f.array_len == 0:
            return (list[element], Field(default_factory=list))
        n = f.array_len
        return (Annotated[list[element], Field(min_length=n, max_length=n)],
                Field(default_factory=lambda: [self._zero(owner, f.type) for _ in range(n)]))

    def _default_factory(self, owner: str, f: FieldSpec) -> Any:
        if f.type in PRIMITIVES and f.type not in _TIME_TYPES:
            return self._zero(owner, f.type)
        if f.type == "time" and owner == "std_msgs/Header":
            # rosbridge's rule: a header (or its stamp) left out is stamped with the current time
            return Field(default_factory=lambda: self._now())
        return Field(default_factory=_Zero(lambda: self._zero(owner, f.type), not self._stamps_now(f.type)))

    def _stamps_now(self, ftype: str) -> bool:
        """Whether a zero `ftype` holds a header, whose stamp defaults to the time it is made."""
        if ftype == "std_msgs/Header":
            return True
        spec = self._specs.get(ftype)
        return spec is not None and any(self._stamps_now(f.type) for f in spec.fields)

    def _zero(self, owner: str, ftype: str) -> Any:
        if ftype in _INT_TYPES:
            return 0
        if ftype in _FLOAT_TYPES:
            return 0.0
        if ftype == "bool":
            return False
        if ftype == "string":
            return ""
        return self._element_annotation(owner, ftype)()

    def _now(self) -> BaseModel:
        return self._time_models["time"].model_validate(self.now())

    def now(self) -> dict[str, int]:
        """The server clock's current time as a header stamp in this registry's style (plain data, so that a
        message stamped with it takes the bus's plain path)."""
        return self.stamp(self.clock.time())

    def stamp(self, t: float) -> dict[str, int]:
        """A time on the server clock (Unix seconds) as a header stamp in this registry's style."""
        secs, nsecs = divmod(round(t * 1e9), 1_000_000_000)
        return {"secs": secs, "nsecs": nsecs} if self.time_style == "ros1" else {"sec": secs, "nanosec": nsecs}

    def codec(self, name: str) -> PlainCodec:
        """The known message type's validation to plain dicts and their JSON (the publish hot path)."""
        name = normalize_type_name(name)
        codec = self._codecs.get(name)
        if codec is None:
            codec = self._codecs[name] = PlainCodec(self.model(name))
        return codec

    def validate(self, name: str, data: Any) -> BaseModel:
        """Validates `data` as type `name`, filling ROS defaults. Raises pydantic's ValidationError."""
        return self.model(name).model_validate({} if data is None else data)

    # ---- encodings ------------------------------------------------------------------------------------------
    def to_cbor_value(self, name: str, message: BaseModel) -> dict[str, Any]:
        """The message as CBOR wants it: bytes stay bytes, numeric arrays become typed-array tags."""
        return self._cbor_walk(self.spec(name), message.model_dump(mode="python", by_alias=True))

    def _cbor_walk(self, spec: MessageSpec, data: dict[str, Any]) -> dict[str, Any]:
        out = dict(data)
        for f in spec.fields:
            value = data[f.name]
            if f.array_len is not None and f.type in _CBOR_TYPED_ARRAY_TAGS and not f.is_byte_array:
                tag, code = _CBOR_TYPED_ARRAY_TAGS[f.type]
                out[f.name] = cbor2.CBORTag(tag, array.array(code, value).tobytes())
            elif f.type in self._specs:
                sub = self._specs[f.type]
                out[f.name] = [self._cbor_walk(sub, v) for v in value] if f.array_len is not None \
                    else self._cbor_walk(sub, value)
        return out

    def serialize_ros1(self, name: str, message: BaseModel) -> bytes:
        """ROS 1 wire format (little-endian, uint32 length prefixes), as `cbor-raw` subscribers expect."""
        out = bytearray()
        self._ros1_write(self.spec(name), message, out)
        return bytes(out)

    def _ros1_write(self, spec: MessageSpec, message: BaseModel, out: bytearray) -> None:
        for f in spec.fields:
            value = getattr(message, f.name)
            if f.array_len is None:
                self._ros1_scalar(f.type, value, out)
                continue
            if f.array_len == 0:
                out += struct.pack("<I", len(value))
            if f.is_byte_array:
                out += value
            else:
                for item in value:
                    self._ros1_scalar(f.type, item, out)

    def _ros1_scalar(self, ftype: str, value: Any, out: bytearray) -> None:
        if ftype in _INT_TYPES:
            out += struct.pack("<" + _INT_TYPES[ftype][0], value)
        elif ftype in _FLOAT_TYPES:
            out += struct.pack("<" + _FLOAT_TYPES[ftype], value)
        elif ftype == "bool":
            out += struct.pack("<B", 1 if value else 0)
        elif ftype == "string":
            encoded = value.encode("utf-8")
            out += struct.pack("<I", len(encoded)) + encoded
        elif ftype in _TIME_TYPES:
            out += struct.pack("<Ii" if ftype == "duration" else "<II", value.secs, value.nsecs)
        else:
            self._ros1_write(self._specs[ftype], value, out)

    # ---- rosapi ---------------------------------------------------------------------------------------------
    def typedefs(self, name: str) -> list[dict[str, Any]]:
        """rosapi/TypeDef records for `name` and every type it contains, as `/rosapi/message_details` returns."""
        result: list[dict[str, Any]] = []
        seen: set[str] = set()

        def visit(type_name: str) -> None:
            if type_name in seen:
                return
            seen.add(type_name)
            spec = self._specs[type_name]
            result.append({
                "type": type_name,
                "fieldnames": [f.name for f in spec.fields],
                "fieldtypes": [f.ros_type for f in spec.fields],
                "fieldarraylen": [-1 if f.array_len is None else f.array_len for f in spec.fields],
                "examples": [self._example(f) for f in spec.fields],
                "constnames": [c.name for c in spec.constants],
                "constvalues": [c.value for c in spec.constants],
            })
            for f in spec.fields:
                if f.type in self._specs:
                    visit(f.type)

        visit(normalize_type_name(name))
        return result

    @staticmethod
    def _example(f: FieldSpec) -> str:
        if f.array_len is not None:
            return "[]"
        if f.type in _INT_TYPES:
            return "0"
        if f.type in _FLOAT_TYPES:
            return "0.0"
        if f.type == "bool":
            return "False"
        if f.type == "string":
            return ""
        return "{}"


def describe_validation_error(exc: ValidationError, prefix: str = "") -> str:
    """One line a person can act on: which field, what was wrong, what was given."""
    problems = []
    for err in exc.errors(include_url=False)[:5]:
        loc = ".".join(str(p) for p in err["loc"])
        where = f"{prefix}.{loc}" if prefix and loc else (prefix or loc or "message")
        given = err.get("input")
        shown = repr(given)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        if err["type"] == "missing":
            problems.append(f"'{where}' is required")
        elif err["type"] == "extra_forbidden":
            problems.append(f"'{where}' is not a field of this type")
        else:
            problems.append(f"'{where}': {err['msg']} (got {shown})")
    more = len(exc.errors()) - len(problems)
    return "; ".join(problems) + (f"; and {more} more" if more > 0 else "")


class PlainCodec:
    """A known type's validation and JSON output without model instances: its model's own core schema with every
    model turned into a typed dict, so the rules (strictness, bounds, defaults, aliases, base64) are the model's,
    read from it rather than written twice.

    Why: building six model instances for a PoseStamped and dumping them again was a quarter of a relayed
    publish's cost (py-spy); validated to plain dicts and written by the same Rust serializer, it is well under
    half. Features that read the message still get the model, made on first use (Published.value)."""

    def __init__(self, model: type[BaseModel]) -> None:
        self.model = model
        self.validator = SchemaValidator(_as_typed_dicts(model.__pydantic_core_schema__, times_in_rust=True))
        self.serializer = SchemaSerializer(_as_typed_dicts(model.__pydantic_core_schema__))

    def validate(self, data: Any) -> dict[str, Any]:
        """Raises ValidationError wherever the model's validation would on JSON data (tests/test_hot_path.py),
        and also on model instances inside `data`, which the model takes: callers then ask the model."""
        return self.validator.validate_python({} if data is None else data)

    def to_json(self, plain: dict[str, Any]) -> str:
        return self.serializer.to_json(plain, by_alias=True).decode("utf-8")

    def to_model(self, plain: dict[str, Any]) -> BaseModel:
        return self.model.model_validate(plain)


def _as_typed_dicts(node: Any, times_in_rust: bool = False) -> Any:
    """A copy of a core schema with 'model' nodes replaced by equivalent 'typed-dict' nodes. `times_in_rust`: a
    time's two spellings are read without calling its model's before-validator (a Python call per stamp, most of
    a header's validation), which stays for what they do not cover; for validation only (the union it makes
    would slow the serializer down)."""
    if isinstance(node, list):
        return [_as_typed_dicts(item, times_in_rust) for item in node]
    if not isinstance(node, dict):
        return node
    kind = node.get("type")
    if kind == "model":
        inner = _as_typed_dicts(node["schema"], times_in_rust)
        config = node.get("config", {})
        target = inner
        while target.get("type") != "typed-dict":  # a model validator wraps the fields (ROS time's two spellings)
            target = target["schema"]
        target["config"] = config
        target["extra_behavior"] = config.get("extra_fields_behavior", "ignore")
        target["strict"] = config.get("strict", False)
        names = getattr(node["cls"], "ROS2_NAMES", None) if times_in_rust else None
        if names is not None:  # {secs, nsecs} or {sec, nanosec}; the model's rule for both mixed
            inner = {"type": "union", "mode": "left_to_right", "choices": [
                target, {**target, "config": {**config, "validate_by_name": False},
                         "fields": {name: {**f, "validation_alias": names[name]}
                                    for name, f in target["fields"].items()}},
                inner]}
        if "ref" in node:
            inner["ref"] = node["ref"]
        return inner
    if kind == "model-fields":
        return {"type": "typed-dict", "fields": {
            name: {"type": "typed-dict-field", "schema": _as_typed_dicts(field["schema"], times_in_rust),
                   "required": field["schema"].get("type") != "default",
                   **{k: field[k] for k in ("validation_alias", "serialization_alias") if k in field}}
            for name, field in node["fields"].items()}}
    out = {key: (_as_typed_dicts(value, times_in_rust) if key != "cls" else value) for key, value in node.items()}
    if kind == "default" and "default_factory" in out:  # model defaults become their plain form
        factory = out["default_factory"]
        if isinstance(factory, _Zero) and factory.constant:  # made once, copied for each message: a model built
            plain = _plain_default(factory())  # and dumped per message was most of a command's validation
            out["default_factory"] = lambda plain=plain: _copy_plain(plain)
        else:
            out["default_factory"] = lambda factory=factory: _plain_default(factory())
    return out


class _Zero:
    """A field's default factory that makes its type's zero; `constant`: the zero is the same whenever made (it
    holds no header, whose stamp is the time of making), so the plain path makes its plain form once."""

    def __init__(self, make: Callable[[], Any], constant: bool) -> None:
        self.make = make
        self.constant = constant

    def __call__(self) -> Any:
        return self.make()


def _copy_plain(value: Any) -> Any:
    """A copy of plain data (dicts, lists, scalars) that shares no mutable part with the original."""
    if isinstance(value, dict):
        return {key: _copy_plain(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_copy_plain(item) for item in value]
    return value


def _plain_default(value: Any) -> Any:
    if isinstance(value, BaseModel):
        return value.model_dump(mode="python")
    if isinstance(value, list):
        return [_plain_default(v) for v in value]
    return value
