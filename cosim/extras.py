"""The optional extras: which heavy packages a feature needs, and the one-line error when one is missing.

``pip install .`` (or ``cosim``) installs what a run needs; each heavy feature is an extra of
pyproject.toml: ``lmi`` (cvxpy, Clarabel: the LMI designs of IJC 2018), ``export`` (pyarrow,
asammdf, rosbags: Parquet, MF4 and ROS 2 bag exports; MF4 logs and ROS 2 bags imported),
``campaign`` (distributed, pyarrow: the campaign engine and its results table), ``plot``
(matplotlib: figures), ``live`` (foxglove-sdk: the Foxglove WebSocket server), ``fmi`` (FMPy,
pythonfmu3, pint: FMU plants and ``cosim fmu``); ``all`` is every one of them.

``require`` imports a package of an extra or raises ``MissingExtra`` naming the extra;
``missing_extra`` turns an ImportError raised deeper down (a lazy import in an estimator's design,
say) into the same error, which the command line prints as its one line.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from cosim.errors import CosimError

#: Extra → the top-level modules of its packages.
EXTRAS: dict[str, tuple[str, ...]] = {
    "lmi": ("cvxpy", "clarabel"),
    "export": ("pyarrow", "asammdf", "rosbags"),
    "campaign": ("distributed", "pyarrow"),
    "plot": ("matplotlib",),
    "live": ("foxglove", "websockets"),
    "fmi": ("fmpy", "pythonfmu3", "pint"),
}
#: Top-level module → the first extra that brings it (a feature needing it from another extra names that one).
MODULE_EXTRA = {module: extra for extra, modules in reversed(EXTRAS.items()) for module in modules}
#: Top-level module → the package that installs it, where the names differ.
PACKAGE = {"foxglove": "foxglove-sdk"}


class MissingExtra(CosimError):
    """A feature needs a package of an extra that is not installed."""

    def __init__(self, feature: str, extra: str, module: str) -> None:
        super().__init__(
            f"{feature} needs the '{extra}' extra ({PACKAGE.get(module, module)} is not installed): "
            f"pip install 'cosim[{extra}]'"
        )
        self.feature, self.extra, self.module = feature, extra, module


def missing_extra(error: ImportError, feature: str, extra: str | None = None) -> MissingExtra | None:
    """The MissingExtra for ``error`` if it is the import of an extra's package failing, else None;
    ``extra`` names the feature's extra where several bring the package."""
    top = (error.name or "").split(".")[0]
    if top not in MODULE_EXTRA:
        return None
    return MissingExtra(feature, extra if extra and top in EXTRAS[extra] else MODULE_EXTRA[top], top)


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
