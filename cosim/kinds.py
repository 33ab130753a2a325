"""Kinds: the one registry of the parts a scenario names by ``kind`` (estimators, controllers,
fault models, plants) and of the plugins that add more.

A name resolves, in this order, from

1. the group's built-in table, ``name -> "module:attribute"``, imported when the name is first
   looked up (a node process that runs a Kalman filter imports neither the LMI designs nor SciPy's
   optimizer);
2. the name itself as a module path, ``"package.module:ClassName"``, or a file path,
   ``"/path/to/observers.py:ClassName"`` (a scenario's relative ``observers.py:ClassName`` is made
   absolute against the scenario's folder when it is loaded; the file's folder joins the import
   path, so the file may import its neighbours);
3. the entry points of the installed distributions in the group's entry-point group
   (``cosim.estimators``, ``cosim.controllers``, ``cosim.faults``, ``cosim.plants``), read once per
   process and only for a name that is neither built in nor a module path.

What a name resolves to is checked once against its group's contract (for a class: a subclass of
the group's base with nothing abstract left and its parameters a dataclass; its declared name the
one it was looked up by), and remembers where it came from (``Origin``). Every problem is one
``KindError`` line naming the kind and what is wrong with it.
"""

from __future__ import annotations

import difflib
import functools
import importlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

T = TypeVar("T")


class KindError(KeyError):
    """A kind that is unknown, cannot be imported or breaks its group's contract: one line."""

    def __str__(self) -> str:
        return str(self.args[0])


@dataclass(frozen=True)
class Origin:
    """Where a kind came from: the built-in table, an installed distribution's entry point, or a
    module path given as its name; ``target`` is the ``module:attribute`` it was imported from."""

    source: Literal["built-in", "entry point", "module path"]
    target: str
    distribution: str = ""
    """The distribution (name and version) that declares an entry point."""

    def __str__(self) -> str:
        if self.source == "entry point":
            return f"entry point of {self.distribution} ({self.target})"
        return "module path" if self.source == "module path" else f"built-in ({self.target})"


class Kinds(Mapping[str, T]):
    """One group's kinds by name: a read-only mapping whose lookups resolve as the module says.

    ``what`` names one of them in messages ("estimator"), ``group`` is the entry-point group and
    ``builtin`` maps each built-in name to ``"module:attribute"`` (imported on first lookup) or to
    the object itself. The contract: a kind is a subclass of ``base`` that implements every abstract
    method, with its ``params`` attribute a dataclass (None: the class itself is one), or, with
    ``instance``, an instance of ``base``; it declares its name in its attribute ``key``; and
    ``check`` (if given) finds nothing more wrong with it.
    """

    def __init__(
        self,
        what: str,
        group: str,
        builtin: Mapping[str, str | T],
        base: type,
        *,
        params: str | None = "Params",
        instance: bool = False,
        key: str = "kind",
        check: Callable[[Any], list[str]] | None = None,
    ) -> None:
        self.what, self.group, self.base, self.key = what, group, base, key
        self._builtin = dict(builtin)
        self._params, self._instance, self._check = params, instance, check
        self._resolved: dict[str, T] = {}

    def __getitem__(self, name: str) -> T:
        if name not in self._resolved:
            self._resolved[name] = self._resolve(name)
        return self._resolved[name]

    def origin(self, name: str) -> Origin:
        """Where the kind ``name`` comes from, without importing it (a KindError if unknown)."""
        if name in self._builtin:
            entry = self._builtin[name]
            return Origin("built-in", entry if isinstance(entry, str) else _reference(entry))
        if ":" in name:
            return Origin("module path", name)
        point = _entry_points(self.group).get(name)
        if point is None:
            raise KindError(self._unknown(name))
        dist = f"{point.dist.name} {point.dist.version}" if point.dist is not None else "an unnamed distribution"
        return Origin("entry point", f"{point.module}:{point.attr}", dist)

    def __contains__(self, name: object) -> bool:
        """A built-in name without importing it; any other name if it resolves."""
        if not isinstance(name, str):
            return False
        if name in self._builtin or name in self._resolved:
            return True
        try:
            self[name]
        except KindError:
            return False
        return True

    def __iter__(self) -> Iterator[str]:
        """The built-in names, then the installed entry points' (a module path is not listed)."""
        return iter(dict.fromkeys([*self._builtin, *_entry_points(self.group)]))

    def __len__(self) -> int:
        return sum(1 for _ in self)

    def _resolve(self, name: str) -> T:
        origin = self.origin(name)
        entry = self._builtin.get(name)
        if entry is not None and not isinstance(entry, str):
            found = entry
        elif origin.source == "built-in":
            found = _attribute(origin.target)  # a built-in that does not import is a bug: its traceback
        else:
            found = self._load(name, origin.target)
        problems = self._is_a(found) or [*self._naming(name, found, origin), *self._members(found)]
        if problems:
            raise KindError(f"{self.what} {name!r} ({origin}): {'; '.join(problems)}")
        return found

    def _load(self, name: str, target: str) -> Any:
        """Import a plugin; whatever goes wrong in its module is one line, not its traceback."""
        try:
            return _attribute(target)
        except Exception as error:  # noqa: BLE001 (anything a plugin's module raises on import)
            raise KindError(f"{self.what} {name!r}: cannot import it ({type(error).__name__}: {error})") from None

    def _is_a(self, found: Any) -> list[str]:
        """What it is: a subclass (an instance) of the group's base."""
        base = f"{self.base.__module__}.{self.base.__qualname__}"
        if self._instance:
            return [] if isinstance(found, self.base) else [f"{found!r} is not an instance of {base}"]
        is_subclass = isinstance(found, type) and issubclass(found, self.base)
        return [] if is_subclass else [f"{found!r} is not a subclass of {base}"]

    def _members(self, found: Any) -> list[str]:
        """What a class kind lacks: an implementation of an abstract method, parameters as a dataclass."""
        problems = self._check(found) if self._check is not None else []
        if self._instance:
            return problems
        if missing := sorted(getattr(found, "__abstractmethods__", ())):
            problems.append(f"missing {', '.join(missing)}")
        parameters = found if self._params is None else getattr(found, self._params, None)
        if not (isinstance(parameters, type) and "__dataclass_fields__" in vars(parameters)):  # itself decorated
            problems.append(f"{self._params} is not a dataclass" if self._params else "not a dataclass")
        return problems

    def _naming(self, name: str, found: Any, origin: Origin) -> list[str]:
        """A kind declares its name; under a module path any name, else the one it is listed by."""
        declared = getattr(found, self.key, None)
        if not isinstance(declared, str) or not declared:
            return [f"declares no {self.key} (a string)"]
        if origin.source != "module path" and declared != name:
            return [f"its {self.key} is {declared!r}, not {name!r}"]
        return []

    def _unknown(self, name: str) -> str:
        known = sorted(self)
        close = difflib.get_close_matches(name, known, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return (
            f"unknown {self.what} {name!r}{hint}; known {self.what}s: {', '.join(known)} "
            "(or a module path, package.module:Name)"
        )


def _reference(found: Any) -> str:
    """The ``module:attribute`` of a class or function."""
    return f"{found.__module__}:{found.__qualname__}"


def _attribute(reference: str) -> Any:
    """The object ``module:attribute`` (the attribute may be dotted) names; the module may be a
    Python file's path (``.../observers.py``)."""
    module, _, attribute = reference.partition(":")
    imported = _module_file(module) if module.endswith(".py") else importlib.import_module(module)
    return functools.reduce(getattr, attribute.split("."), imported)


def is_file_reference(name: str) -> bool:
    """Whether a kind names a class in a Python file (``observers.py:ClassName``)."""
    return name.partition(":")[0].endswith(".py")


@functools.cache
def _module_file(path: str) -> Any:
    """The module of a Python file, imported once per process under a name unique to its path."""
    import hashlib
    import importlib.util
    import sys
    from pathlib import Path

    file = Path(path)
    if not file.is_absolute() or not file.is_file():
        raise FileNotFoundError(f"no Python file {path} (a path relative to the scenario file)")
    name = f"cosim_plugin_{file.stem}_{hashlib.sha256(str(file).encode()).hexdigest()[:8]}"
    spec = importlib.util.spec_from_file_location(name, file)
    assert spec is not None and spec.loader is not None  # a .py file always has a source loader
    module = importlib.util.module_from_spec(spec)
    if str(file.parent) not in sys.path:
        sys.path.append(str(file.parent))  # its neighbours import as they would next to it
    sys.modules[name] = module  # before running it: dataclasses look their module up
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


@functools.cache
def _entry_points(group: str) -> dict[str, Any]:
    """The installed entry points of a group, by name; read once per process (``rescan``), and
    imported here: a process that looks up only built-in kinds never reads the installed metadata."""
    from importlib import metadata

    return {point.name: point for point in metadata.entry_points(group=group)}


def rescan() -> None:
    """Forget the installed entry points read so far: for a process that installs a plugin."""
    _entry_points.cache_clear()
