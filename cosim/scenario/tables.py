"""The vocabulary of scenario tables: strict tables, number types, and readable validation errors.

Every table of a scenario is a ``Strict`` pydantic model: unknown keys are refused with the allowed
ones, numbers must be finite, and values are not coerced. ``problem_path`` and ``problem_message``
turn pydantic's errors into the one-line messages cosim prints (``faults[0].value: ...``).
"""

from __future__ import annotations

import difflib
import tomllib
from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator


def loads_toml(text: str) -> dict[str, Any]:
    """``tomllib.loads``, with text nested deeper than its recursive parser goes (a thousand
    ``[[[...]]]``) a TOMLDecodeError like any other invalid TOML, not a RecursionError."""
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError(
            "arrays or inline tables nested thousands deep (a scenario needs a few)"
        ) from None


Identifier = Annotated[str, Field(pattern=r"^[A-Za-z][A-Za-z0-9_]{0,23}$")]
NonNegative = Annotated[float, Field(ge=0)]
Positive = Annotated[float, Field(gt=0)]
Probability = Annotated[float, Field(ge=0, le=1)]


def as_list(value: Any) -> Any:
    """A single number or table stands for a one-element list (applied to every channel)."""
    return [value] if isinstance(value, (int, float, dict)) and not isinstance(value, bool) else value


#: A list of numbers; a single number applies to every channel.
Vector = Annotated[list[float], BeforeValidator(as_list)]


class Strict(BaseModel):
    """A table whose keys are all known; an unknown key is reported with the allowed ones."""

    model_config = ConfigDict(frozen=True, strict=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            allowed = list(cls.model_fields)
            for key in data:
                if key not in allowed:
                    close = difflib.get_close_matches(str(key), allowed, n=1)
                    hint = f" (did you mean {close[0]!r}?)" if close else ""
                    raise ValueError(f"unknown key {key!r}{hint}; allowed keys: {', '.join(allowed)}")
        return data


#: The union tag of a table whose kind is a plugin's (``cosim.scenario.faults.PluginFaultSpec``), and
#: of one whose kind is a plugin's bus fault (``PluginBusFaultSpec``).
PLUGIN_TAG = "plugin"
PLUGIN_BUS_TAG = "plugin-bus"


def problem_path(loc: tuple[Any, ...], data: Any) -> str:
    """A readable field path, without the union tags pydantic inserts (``faults[0].bias.value``
    becomes ``faults[0].value``): a tag is the first item that names the current table's kind."""
    parts: list[str] = []
    node, tag_pending = data, True
    for item in loc:
        if not isinstance(node, (dict, list)) and parts:
            break  # a number standing for a table (a constant waveform): the number is the culprit
        if isinstance(item, int):
            parts.append(f"[{item}]")
            node = node[item] if isinstance(node, list) and item < len(node) else None
        elif tag_pending and isinstance(node, dict) and item in (node.get("kind"), PLUGIN_TAG, PLUGIN_BUS_TAG):
            tag_pending = False
            continue
        else:
            parts.append(f".{item}" if parts else str(item))
            node = node.get(item) if isinstance(node, dict) else None
        tag_pending = True
    return "".join(parts) or "(top level)"


def problem_message(error: Mapping[str, Any]) -> str:
    """A readable message for one of pydantic's errors (its ``ErrorDetails``)."""
    kind = error["type"]
    if kind == "missing":
        return "required but missing"
    if kind == "union_tag_invalid":
        tags = error.get("ctx", {}).get("expected_tags", "")
        return f"unknown kind {error['input'].get('kind')!r}; expected one of {tags}"
    if kind == "union_tag_not_found":
        return "needs a 'kind' key"
    if kind in ("model_attributes_type", "dict_type"):
        return f"expected a table (where a waveform is expected, a number also works), got {error['input']!r}"
    message = error["msg"]
    return message.removeprefix("Value error, ")
