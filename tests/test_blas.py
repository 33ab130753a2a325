"""A run computes on one BLAS thread (``cosim.blas``): its plan, its tick loop, the processes it
starts, a campaign's batches; the same numbers whatever the machine's core count."""

from __future__ import annotations

import os
from types import SimpleNamespace

import scipy.linalg  # noqa: F401 (its OpenBLAS loaded: the limits below reach it)
from threadpoolctl import threadpool_info, threadpool_limits

from cosim import scenario
from cosim.blas import ONE_THREAD_ENV, one_thread
from cosim.run import launcher
from cosim.run.runner import Run


def blas_threads() -> dict[str, int]:
    """Each BLAS library loaded (by its file) and its threads."""
    libraries = [library for library in threadpool_info() if library["user_api"] == "blas"]
    return {library["filepath"]: library["num_threads"] for library in libraries}


def test_one_thread_limits_numpy_s_and_scipy_s_blas_and_restores_them():
    with threadpool_limits(limits=3, user_api="blas"):
        given = blas_threads()
        with one_thread():
            assert {blas_threads()[path] for path in given} == {1}
        assert blas_threads() == given


def test_a_run_ticks_on_one_blas_thread(tmp_path):
    seen: list[dict[str, int]] = []
    with threadpool_limits(limits=3, user_api="blas"):
        given = blas_threads()
        run = Run(scenario.load("masses-bias"), tmp_path / "run.mcap", 0, duration=0.2, interface="virtual")
        result = run.execute(on_start=lambda _: seen.append(blas_threads()))
        assert {path: blas_threads()[path] for path in given} == given  # given back after the run
    assert result.status == "completed" and {seen[0][path] for path in given} == {1}


def test_a_node_process_starts_with_its_blas_on_one_thread(monkeypatch, tmp_path):
    """Set in its environment before it imports NumPy: whatever BLAS it loads later is limited."""
    started: list[dict[str, str]] = []

    class Started:
        def __init__(self, args: list[str], **options: object) -> None:
            started.append(dict(options["env"]))  # type: ignore[call-overload]

    monkeypatch.setattr(launcher.subprocess, "Popen", Started)
    launcher.ProcessNode(SimpleNamespace(name="kf", to_json=lambda: "{}"), tmp_path)  # type: ignore[arg-type]
    assert started and all(started[0][name] == value for name, value in ONE_THREAD_ENV.items())
    assert started[0]["PATH"] == os.environ["PATH"]  # the rest of its environment is the runner's
