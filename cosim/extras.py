"""The optional extras: which heavy packages a feature needs, and the one-line error when one is missing.

``pip install .`` (or ``cosim``) installs what a run needs; each heavy feature is an extra of
pyproject.toml: ``lmi`` (cvxpy, Clarabel: the LMI designs of IJC 2018), ``export`` (pyarrow,
asammdf, rosbags: Parquet, MF4 and ROS 2 bag exports; MF4 logs and ROS 2 bags imported),
``campaign`` (distributed, pyarrow: the campaign engine and its results table), ``dataset`` (the
campaign extra, and pandas and HuggingFace ``datasets``, which ``docs/datasets.md`` loads a data set
with), ``plot`` (matplotlib: figures), ``live`` (foxglove-sdk: the Foxglove WebSocket server),
``fmi`` (FMPy, pythonfmu3, pint: FMU plants and ``cosim fmu``); ``all`` is every one of them.

``require`` imports a package of an extra or raises ``MissingExtra`` naming the extra;
``missing_extra`` turns an ImportError raised deeper down (a lazy import in an estimator's design,
say) into the same error, which the command line prints as its one line. ``require_all`` checks,
before a command does anything, every extra it will need (its engine, its figures, what its
scenarios' plants and estimators need: ``cosim.run.needs``) and names all that are missing in one
line, rather than one at a time as each is reached.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Iterable, Mapping
from types import ModuleType

from cosim.errors import CosimError

#: Extra → the top-level modules of its packages.
EXTRAS: dict[str, tuple[str, ...]] = {
    "lmi": ("cvxpy", "clarabel"),
    "export": ("pyarrow", "asammdf", "rosbags"),
    "campaign": ("distributed", "pyarrow"),
    "dataset": ("distributed", "pyarrow", "pandas", "datasets"),
    "plot": ("matplotlib",),
    "live": ("foxglove", "websockets"),
    "fmi": ("fmpy", "pythonfmu3", "pint"),
}
#: Top-level module → the first extra that brings it (a feature needing it from another extra names that one).
MODULE_EXTRA = {module: extra for extra, modules in reversed(EXTRAS.items()) for module in modules}
#: Top-level module → the package that installs it, where the names differ.
PACKAGE = {"foxglove": "foxglove-sdk"}


class MissingExtra(CosimError):
    """A feature needs packages of extras that are not installed (``missing``: extra → modules)."""

    def __init__(self, feature: str, missing: Mapping[str, Iterable[str]]) -> None:
        self.feature, self.missing = feature, {extra: list(modules) for extra, modules in missing.items()}
        super().__init__(f"{feature} needs {missing_words(self.missing)}")


def missing_words(missing: Mapping[str, list[str]]) -> str:
    """``the 'lmi' extra (cvxpy is not installed): pip install 'cosim[lmi]'``, for one extra or several."""
    extras = list(missing)
    packages = [PACKAGE.get(module, module) for modules in missing.values() for module in modules]
    names = " and ".join(filter(None, [", ".join(f"'{e}'" for e in extras[:-1]), f"'{extras[-1]}'"]))
    verb = "is" if len(packages) == 1 else "are"
    return (
        f"the {names} extra{'s' if len(extras) > 1 else ''} ({', '.join(packages)} {verb} not installed): "
        f"pip install 'cosim[{','.join(extras)}]'"
    )


def not_installed(needs: Mapping[str, Iterable[str]]) -> dict[str, list[str]]:
    """Of ``needs`` (extra → the modules a feature needs of it), the modules not installed, by extra;
    found without importing them (a command checks before it starts)."""
    out: dict[str, list[str]] = {}
    for extra, modules in needs.items():
        absent = [m for m in dict.fromkeys(modules) if not _installed(m.split(".")[0])]
        if absent:
            out[extra] = absent
    return out


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a parent that fails to import; a module set to None in sys.modules
        return False


def require_all(feature: str, needs: Mapping[str, Iterable[str]]) -> None:
    """MissingExtra naming every extra of ``needs`` (extra → modules) that is not installed, at once."""
    missing = not_installed(needs)
    if missing:
        raise MissingExtra(feature, missing)


def missing_extra(error: ImportError, feature: str, extra: str | None = None) -> MissingExtra | None:
    """The MissingExtra for ``error`` if it is the import of an extra's package failing, else None;
    ``extra`` names the feature's extra where several bring the package."""
    top = (error.name or "").split(".")[0]
    if top not in MODULE_EXTRA:
        return None
    return MissingExtra(feature, {extra if extra and top in EXTRAS[extra] else MODULE_EXTRA[top]: [top]})


def require(module: str, feature: str, extra: str | None = None) -> ModuleType:
    """Import ``module`` (a package of an extra, or one of its submodules) for ``feature``, e.g.
    ``require("pyarrow.parquet", "cosim export --to parquet")``; MissingExtra if it is not installed
    (naming ``extra`` where several extras bring the package)."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        missing = missing_extra(error, feature, extra)
        if missing is None:
            raise
        raise missing from None
