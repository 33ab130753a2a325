"""Settings that change a scenario from outside its file: ``KEY=VALUE`` with KEY a path into the
scenario (``duration``, ``faults[0].value``, ``estimators[1].params.epsilon``, ``bus.fd``) and
VALUE in TOML (``5``, ``[0.5, 0, 0]``, ``"text"``, ``true``, ``{ kind = "sine", ... }``).

A setting is applied to the scenario's TOML data as read from its file, and the result goes
through the same validation as a file (``cosim.scenario.load.validate``), so a bad value gets the
same one-line error naming its path. A path may create a table that the file leaves out
(``bus.fd``) and may add an item one past the end of a list (``faults[1]`` of a scenario with one
fault, given as a whole table).
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import replace
from typing import Any

from cosim.errors import ScenarioError
from cosim.scenario.load import LoadedScenario, folder_of, validate
from cosim.scenario.tables import loads_toml

_PART = re.compile(r"([A-Za-z_][A-Za-z0-9_-]*)((?:\[\d+\])*)")
_BARE = re.compile(r"^[A-Za-z_][A-Za-z0-9_.:-]*$")


def parse_value(text: str) -> Any:
    """A TOML value; a bare word (``virtual``, ``kalman``) stands for itself."""
    try:
        return loads_toml(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError:
        if _BARE.match(text.strip()):
            return text.strip()
        raise ScenarioError(
            f'{text!r} is not a TOML value: give a number (0.5), true/false, "quoted text", a list ([1, 0, 0]) '
            f'or an inline table ({{ kind = "sine", amplitude = 1.0, frequency = 0.5 }})'
        ) from None


def parse_setting(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` → (KEY, value)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ScenarioError(
            f"--set {text!r}: expected KEY=VALUE, e.g. --set duration=5 or --set 'faults[0].value=[0.5, 0, 0]'"
        )
    try:
        return key, parse_value(value)
    except ScenarioError as error:
        raise ScenarioError(f"--set {key}: {error}") from None


def path_parts(key: str) -> list[str | int]:
    """``faults[0].value`` → ["faults", 0, "value"]; a ScenarioError for a malformed path."""
    parts: list[str | int] = []
    for piece in key.split("."):
        match = _PART.fullmatch(piece)
        if match is None:
            raise ScenarioError(
                f"--set {key}: {piece!r} is not a key; write a path like duration, faults[0].value or bus.fd"
            )
        parts.append(match.group(1))
        parts += [int(index) for index in re.findall(r"\[(\d+)\]", match.group(2))]
    return parts


def _where(parts: list[str | int]) -> str:
    text = ""
    for part in parts:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else part)
    return text


def set_path(data: dict[str, Any], key: str, value: Any) -> None:
    """Set ``value`` at the path ``key`` in plain TOML data (tables created as needed)."""
    parts = path_parts(key)
    node: Any = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        here = _where(parts[: depth + 1])
        if isinstance(part, int):
            if not isinstance(node, list):
                raise ScenarioError(
                    f"--set {key}: {_where(parts[:depth]) or 'the scenario'} is not a list, so {here} does not exist"
                )
            if part > len(node):
                items = f"{len(node)} item" + ("" if len(node) == 1 else "s")
                raise ScenarioError(
                    f"--set {key}: {_where(parts[:depth])} has {items}; {here} is beyond its end (add one at index "
                    f"{len(node)})"
                )
            if part == len(node):
                node.append(value if last else {})
        else:
            if not isinstance(node, dict):
                raise ScenarioError(
                    f"--set {key}: {_where(parts[:depth])} is a value, not a table, so {here} does not exist"
                )
            if last:
                node[part] = value
            elif part not in node:
                node[part] = [] if isinstance(parts[depth + 1], int) else {}
        if last:
            if isinstance(part, int):
                node[part] = value
            return
        node = node[part]


def apply(loaded: LoadedScenario, settings: Mapping[str, Any] | Iterable[tuple[str, Any]]) -> LoadedScenario:
    """The scenario with ``settings`` (path → value) applied to its file's data, validated like a file."""
    items = list(settings.items() if isinstance(settings, Mapping) else settings)
    if not items:
        return loaded
    data = loads_toml(loaded.text)
    for key, value in items:
        set_path(data, key, value)
    given = ", ".join(f"{key}={_short(value)}" for key, value in items)
    scenario = validate(data, f"{loaded.source} with --set {given}", folder_of(loaded.source))
    return replace(loaded, scenario=scenario, settings=(*loaded.settings, *items))


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"
