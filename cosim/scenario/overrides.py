"""Settings that change a scenario from outside its file: ``KEY=VALUE`` with KEY a path into the
scenario (``duration``, ``faults[0].value``, ``estimators[1].params.epsilon``, ``bus.fd``) and
VALUE in TOML (``5``, ``[0.5, 0, 0]``, ``"text"``, ``true``, ``{ kind = "sine", ... }``). A key
that holds dots (an FMU's parameter ``mass.m``) is quoted as in TOML:
``plant.fmu.parameters."mass.m"`` (or with single quotes).

A setting is applied to the scenario's TOML data as read from its file, and the result goes
through the same validation as a file (``cosim.scenario.load.validate``), so a bad value gets the
same one-line error naming its path. A path may create a table that the file leaves out
(``bus.fd``) and may add an item one past the end of a list (``faults[1]`` of a scenario with one
fault, given as a whole table).
"""

from __future__ import annotations

import json
import re
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from cosim.errors import ScenarioError
from cosim.scenario.load import BUILTIN_DIR, DEFAULT_SCENARIO, LoadedScenario, folder_of, read_toml_file, validate
from cosim.scenario.spec import Scenario
from cosim.scenario.tables import loads_toml

#: One part of a path: a bare key, or a quoted one (TOML's basic or literal string), then its indices.
_PART = re.compile(r"""(?:([A-Za-z_][A-Za-z0-9_-]*)|"((?:[^"\\]|\\.)*)"|'([^']*)')((?:\[\d+\])*)""")
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
    """``faults[0].value`` → ["faults", 0, "value"], ``plant.fmu.parameters."mass.m"`` → [..., "mass.m"];
    a ScenarioError for a malformed path."""
    parts: list[str | int] = []
    position = 0
    while True:
        match = _PART.match(key, position)
        if match is None or match.end() == position:
            piece = key[position:].split(".", 1)[0]
            raise ScenarioError(
                f"--set {key}: {piece!r} is not a key; write a path like duration, faults[0].value or bus.fd "
                '(quote a key with dots: plant.fmu.parameters."mass.m")'
            )
        bare, basic, literal, indices = match.groups()
        parts.append(bare if bare is not None else literal if literal is not None else _unescaped(basic))
        parts += [int(index) for index in re.findall(r"\[(\d+)\]", indices)]
        position = match.end()
        if position == len(key):
            return parts
        if key[position] != ".":
            raise ScenarioError(f"--set {key}: expected a '.' after {key[:position]!r}")
        position += 1


def _unescaped(basic: str) -> str:
    """A TOML basic string's content, its escapes resolved (by TOML itself)."""
    return str(tomllib.loads(f'k = "{basic}"')["k"])


def _where(parts: list[str | int]) -> str:
    text = ""
    for part in parts:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            name = part if re.fullmatch(r"[A-Za-z_][A-Za-z0-9_-]*", part) else json.dumps(part)
            text += f".{name}" if text else name
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
    """The scenario with ``settings`` (path → value) applied to its file's data after those it has
    already, validated like a file."""
    items = list(settings.items() if isinstance(settings, Mapping) else settings)
    if not items:
        return loaded
    every = (*loaded.settings, *items)
    return replace(loaded, scenario=_validated(loaded.text, loaded.source, list(every)), settings=every)


def load_with(name_or_path: str | Path | None, settings: Iterable[tuple[str, Any]]) -> LoadedScenario:
    """A scenario file (or built-in) with ``settings`` applied to its data before it is validated at
    all: for a setting without which the file is refused (``plant.fmu.validate = false``)."""
    target = DEFAULT_SCENARIO if name_or_path is None else str(name_or_path)
    text, source, _ = read_toml_file(target, BUILTIN_DIR, "scenario")
    items = list(settings)
    return LoadedScenario(scenario=_validated(text, source, items), source=source, text=text, settings=tuple(items))


def _validated(text: str, source: str, items: list[tuple[str, Any]]) -> Scenario:
    try:
        data = loads_toml(text)
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{source}: invalid TOML: {error}") from None
    for key, value in items:
        set_path(data, key, value)
    given = ", ".join(f"{key}={_short(value)}" for key, value in items)
    return validate(data, f"{source} with --set {given}", folder_of(source))


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"
