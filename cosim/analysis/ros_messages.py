"""A log's JSON topics as ROS 2 messages: a .msg definition made of each topic's JSON Schema, and
its messages made of the logged JSON, for ``cosim export --to rosbag2``.

A topic's type is ``cosim_msgs/msg/<Topic>``, named after the topic (``/truth/state`` →
``TruthState``, ``/can/EST_kalman`` → ``CanESTKalman``). It starts with a ``std_msgs/Header``
stamped with the message's time, then has a field per property of the schema:

- a number is ``float64`` (NaN where the log has null or nothing: a reading not sent);
- an integer ``int64``, a boolean ``bool``, a string ``string``, each ``T[<=1]`` (ROS 2's optional:
  empty for null or nothing) where the schema allows null or does not require it;
- a list ``T[]``; an object a message of its own (``TruthFaultsNoise``), an empty one left out.

Field names follow ROS 2's rules (lower case, digits, single underscores, a letter first:
``AverageRadius`` → ``average_radius``); a comment after each field gives the JSON name where it
differs and the schema's description, which ends with the unit (``[m]``), so that a ROS user sees
units where ROS shows a definition. The definitions go into the bag whole (rosbag2's ``ros2msg``
form: the type, then each type it uses), so readers without a ``cosim_msgs`` package decode them.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from cosim.errors import LogError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

PACKAGE = "cosim_msgs"
HEADER = "std_msgs/msg/Header"
#: What rosbag2 writes between a type's definition and each type it uses.
SEPARATOR = "=" * 80 + "\n"
_SCALARS = {"number": "float64", "integer": "int64", "boolean": "bool", "string": "string"}
_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])")


@dataclass(frozen=True)
class RosField:
    """A field of a generated type: its JSON key, ROS name and kind (``scalar``, ``optional``,
    ``list`` or ``nested``), the ROS base type, and the nested type of an object."""

    key: str
    name: str
    kind: str
    base: str
    nested: RosType | None = None


@dataclass(frozen=True)
class RosType:
    """A generated message type: its name (``cosim_msgs/msg/TruthState``), .msg text and fields."""

    name: str
    text: str
    fields: tuple[RosField, ...]
    uses: tuple[RosType, ...] = field(default=())

    def every(self) -> list[RosType]:
        """This type and every generated type it uses, depth first, each once."""
        found: list[RosType] = []
        for used in (self, *(t for nested in self.uses for t in nested.every())):
            if used.name not in (t.name for t in found):
                found.append(used)
        return found

    def message(self, store: Typestore, payload: dict[str, Any], header: Any = None) -> Any:
        """The ROS message of a logged JSON ``payload`` (``header``: the top type's)."""
        import numpy as np

        values: dict[str, Any] = {} if header is None else {"header": header}
        for f in self.fields:
            value = payload.get(f.key)
            if f.kind == "nested":
                assert f.nested is not None
                values[f.name] = f.nested.message(store, value if isinstance(value, dict) else {})
            elif f.base == "float64":
                values[f.name] = math.nan if value is None else float(value)
            elif f.kind == "scalar":
                values[f.name] = value
            elif f.kind == "optional":
                present = [] if value is None else [value]
                values[f.name] = present if f.base == "string" else np.array(present, dtype=_NUMPY[f.base])
            else:
                items = list(value or ())
                values[f.name] = items if f.base == "string" else np.array(items, dtype=_NUMPY[f.base])
        return store.types[self.name](**values)


_NUMPY = {"int64": "int64", "bool": "bool", "float64": "float64"}


def type_name(topic: str) -> str:
    """The ROS type of a topic: ``/can/EST_kalman_0`` → ``cosim_msgs/msg/CanESTKalman0``."""
    parts = [p for p in re.split(r"[^A-Za-z0-9]+", topic) if p]
    name = "".join(p[0].upper() + p[1:] for p in parts)
    if not name or not name[0].isalpha():
        name = "Topic" + name
    return f"{PACKAGE}/msg/{name}"


def field_name(key: str) -> str:
    """A JSON key as a ROS 2 field name: lower case, digits and single underscores, a letter first."""
    snake = _CAMEL.sub("_", key).lower()
    name = re.sub(r"_+", "_", re.sub(r"[^a-z0-9]", "_", snake)).strip("_")
    return name if name[:1].isalpha() else f"f_{name}".rstrip("_")


def ros_types(schemas: dict[str, dict[str, Any]]) -> dict[str, RosType]:
    """The type of each topic of a log with its JSON Schema; where two topics would give one name
    (``/a/b_c`` and ``/a/bC``), the later one's is numbered (``ABC2``), its nested types too."""
    types: dict[str, RosType] = {}
    used: set[str] = set()
    for topic, schema in schemas.items():
        name, n = type_name(topic), 1
        while True:
            made = ros_type(topic, schema, name if n == 1 else f"{name}{n}")
            names = {t.name for t in made.every()}
            if not names & used:
                break
            n += 1
        types[topic] = made
        used |= names
    return types


def ros_type(topic: str, schema: dict[str, Any], name: str | None = None) -> RosType:
    """The type of a topic with its JSON Schema (named ``name``, or after the topic): a header,
    then a field per property."""
    title = " ".join(str(schema.get("description") or schema.get("title") or "").split())
    intro = f"# {topic}: {title}\n" if title else f"# {topic}\n"
    intro += "# made by cosim export --to rosbag2 of the topic's JSON Schema: units in [brackets]; where the log\n"
    intro += "# has null, a float64 is NaN and an optional (T[<=1]) empty\n"
    return _object(name or type_name(topic), topic, schema, intro, header=True)


def _object(name: str, where: str, schema: dict[str, Any], intro: str, header: bool = False) -> RosType:
    required = set(schema.get("required", ()))
    taken = {"header"} if header else set()
    lines = ["std_msgs/Header header  # stamp: the message's time"] if header else []
    fields: list[RosField] = []
    uses: list[RosType] = []
    for key, prop in schema.get("properties", {}).items():
        ros = _unique(field_name(key), taken)
        comment = _comment(key, ros, prop)
        kinds = prop.get("type", "")
        kinds = [kinds] if isinstance(kinds, str) else list(kinds)
        nullable = "null" in kinds
        kind = next((k for k in kinds if k != "null"), "")
        if kind == "object":
            if not prop.get("properties"):
                continue  # it holds nothing
            nested = _object(name + ros.title().replace("_", ""), f"{where}.{key}", prop, f"# {where}.{key}\n")
            uses.append(nested)
            lines.append(f"{nested.name.replace('/msg/', '/')} {ros}{comment}")
            fields.append(RosField(key, ros, "nested", "", nested))
        elif kind == "array":
            base = _SCALARS.get(prop.get("items", {}).get("type", ""))
            if base is None:
                raise LogError(f"{where}.{key}: a list of {prop.get('items')} has no ROS field type cosim writes")
            lines.append(f"{base}[] {ros}{comment}")
            fields.append(RosField(key, ros, "list", base))
        elif kind in _SCALARS:
            base = _SCALARS[kind]
            optional = base != "float64" and (nullable or key not in required)
            lines.append(f"{base}{'[<=1]' if optional else ''} {ros}{comment}")
            fields.append(RosField(key, ros, "optional" if optional else "scalar", base))
        else:
            raise LogError(f"{where}.{key}: a JSON value of type {prop.get('type')!r} has no ROS field type")
        taken.add(ros)
    return RosType(name, intro + "".join(line + "\n" for line in lines), tuple(fields), tuple(uses))


def _unique(name: str, taken: set[str]) -> str:
    """``name``, or ``name_2``, ``name_3``, ... where two keys give the same field name."""
    found, n = name, 1
    while found in taken:
        n += 1
        found = f"{name}_{n}"
    return found


def _comment(key: str, ros: str, prop: dict[str, Any]) -> str:
    """A field's comment: its JSON key where the name differs, its description (with the unit),
    the values of an enumeration."""
    text = " ".join(str(prop.get("description", "")).split())
    if key != ros:
        text = f"{key}: {text}" if text else key
    if prop.get("enum"):
        text += f" (one of: {', '.join(map(str, prop['enum']))})"
    return f"  # {text.strip()}" if text.strip() else ""


def register(store: Typestore, types: list[RosType]) -> None:
    """Add the generated types (and every type they use) to rosbags' store."""
    from rosbags.typesys import get_types_from_msg

    for top in types:
        for each in top.every():
            if each.name not in store.fielddefs:
                store.register(get_types_from_msg(each.text, each.name))


def definition(store: Typestore, msgtype: str, texts: dict[str, str]) -> str:
    """The definition a bag carries for ``msgtype``, as rosbag2 writes ``ros2msg``: its text, then
    each type it uses (depth first, once) after a separator and ``MSG: pkg/Name``; ``texts`` gives
    the text of a type (with its comments), rosbags' store the others'."""
    order: list[str] = []

    def visit(name: str) -> None:
        for _, (node, detail) in store.fielddefs[name][1]:
            while isinstance(detail, tuple) and isinstance(detail[0], tuple):  # an array or sequence
                node, detail = detail[0]
            if isinstance(detail, str) and detail not in order and detail != msgtype:
                order.append(detail)
                visit(detail)

    def own(name: str) -> str:
        return texts.get(name) or store.generate_msgdef(name, ros_version=2)[0].split(SEPARATOR)[0]

    visit(msgtype)
    return SEPARATOR.join([own(msgtype), *(f"MSG: {name.replace('/msg/', '/')}\n{own(name)}" for name in order)])
