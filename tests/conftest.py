"""Shared fixtures: the default scenario and the built-in scenarios, each run once per session."""

from __future__ import annotations

import locale
import os
from pathlib import Path

import pytest

from cosim import scenario
from cosim.run import run
from tests import suite_groups

ROOT = Path(__file__).resolve().parent.parent


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's own hook, which reads the groups as it finds them
def pytest_collection_modifyitems(items):
    suite_groups.mark(items)


@pytest.fixture(scope="session", autouse=True)
def design_cache_dir(tmp_path_factory):
    """A fresh design cache per test session: no test depends on an earlier run's designs."""
    folder = tmp_path_factory.mktemp("designs")
    previous = os.environ.get("COSIM_CACHE_DIR")
    os.environ["COSIM_CACHE_DIR"] = str(folder)
    yield folder
    if previous is None:
        os.environ.pop("COSIM_CACHE_DIR", None)
    else:
        os.environ["COSIM_CACHE_DIR"] = previous


@pytest.fixture(autouse=True)
def locale_kept():
    """Tests that load an FMU with FMPy in this process (its reference runs) must not leave the
    locale an FMU's runtime set (Dymola's sets C: Python's default text encoding becomes ASCII)."""
    kept = locale.setlocale(locale.LC_ALL)
    yield
    if locale.setlocale(locale.LC_ALL) != kept:
        locale.setlocale(locale.LC_ALL, kept)


@pytest.fixture(scope="session")
def default_loaded():
    return scenario.load()


@pytest.fixture(scope="session")
def default_run(tmp_path_factory, default_loaded):
    """The default scenario, run once; its log is shared by the end-to-end tests."""
    out = tmp_path_factory.mktemp("run") / "default.mcap"
    result = run(default_loaded, out)
    return result


@pytest.fixture(scope="session")
def builtin_run(tmp_path_factory):
    """A built-in scenario at seed 0 on its own bus (node processes over udp_multicast unless it says
    otherwise), run once per session: the frame digests and the reproductions of the papers read the
    same log."""
    runs = {}

    def get(name: str):
        if name not in runs:
            out = tmp_path_factory.mktemp("builtin") / f"{name}.mcap"
            runs[name] = run(scenario.load(name), out, 0)
        return runs[name]

    return get
