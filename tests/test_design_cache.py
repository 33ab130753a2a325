"""The runner's design cache (``cosim.design_cache``) beyond the LMI designs: a pole placement is
kept too, so that a run of the default scenario skips ``scipy.signal`` (a second of every ``cosim
run``), and a run built from the cache is the run built without it. (The LMI designs' own cache test
is in tests/test_reconciliation.py.)"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

import estimators
from cosim import design_cache, scenario
from cosim.run import node
from cosim.run.plan import RunPlan, estimator_record
from estimators import ParameterError

BUILD = """
import sys
import numpy as np
from cosim import scenario
from cosim.run.plan import RunPlan
plan = RunPlan.build(scenario.load())
print('scipy.signal' in sys.modules, np.asarray(plan.estimators['uniform'].L).tobytes().hex())
"""


def test_a_placed_gain_is_cached_and_the_cached_plan_is_the_fresh_one(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    fresh = RunPlan.build(scenario.load())
    assert list(tmp_path.glob("*.json"))  # the placement is stored (it used to store nothing)

    def built() -> tuple[bool, str]:
        out = subprocess.run([sys.executable, "-c", BUILD], capture_output=True, text=True, check=True)
        imported, gain = out.stdout.split()
        return imported == "True", gain

    imported, gain = built()  # a new process: the cache is all it has
    assert not imported and gain == np.asarray(fresh.estimators["uniform"].L).tobytes().hex()
    cached = RunPlan.build(scenario.load())
    for name, estimator in fresh.estimators.items():
        spec = next(e for e in fresh.scenario.estimators if e.name == name)
        assert estimator_record(fresh.codec, name, spec.kind, spec.params, estimator) == estimator_record(
            cached.codec, name, spec.kind, spec.params, cached.estimators[name]
        )  # the log says the same: the given parameters, not the cached gain
    monkeypatch.setenv("COSIM_CACHE_DIR", "off")
    assert built()[0]  # without the cache the node's design is placed again


def test_create_stores_only_what_the_parameters_do_not_carry(tmp_path, monkeypatch):
    """A log's parameters already carry an LMI design (a replay, the plots rebuild from them): nothing
    is stored again; a pole placement they lack is."""
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    plan = RunPlan.build(scenario.load())
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path / "fresh"))
    placed = design_cache.create("pseudoinverse", plan.model, {"poles": [0.75, 0.8, 0.85, 0.9]}, 0.01)
    assert len(list((tmp_path / "fresh").glob("*.json"))) == 1
    again = design_cache.create("pseudoinverse", plan.model, {"poles": [0.75, 0.8, 0.85, 0.9]}, 0.01)
    assert np.array_equal(again.L, placed.L)
    carried = {"poles": [0.75, 0.8, 0.85, 0.9], "gain": placed.L.tolist()}
    design_cache.create("pseudoinverse", plan.model, carried, 0.01)
    assert len(list((tmp_path / "fresh").glob("*.json"))) == 1  # the gain came with the parameters


def test_the_ship_diagnosis_thresholds_are_cached_and_a_cached_plan_tests_residuals_as_a_fresh_one(
    tmp_path, monkeypatch
):
    """COFD's thresholds (numerical integrals of each observer's response to the declared sea: a few
    tenths of a second, every run of a vessel campaign) are kept like a design: the next plan of the
    same problem takes them from the cache, the flat ones and the centred ones, bit for bit."""
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path))
    fresh = RunPlan.build(scenario.load("vessel-nominal")).estimators["fdi"]
    assert fresh.test.centred is not None and len(list(tmp_path.glob("*.json"))) == 1

    def not_again(*args, **kwargs):
        raise AssertionError("the centred bounds were integrated again")

    monkeypatch.setattr(estimators.thresholds, "centred_bounds", not_again)
    cached = RunPlan.build(scenario.load("vessel-nominal")).estimators["fdi"]
    assert np.array_equal(cached.test.flat, fresh.test.flat) and np.array_equal(cached.test.centred, fresh.test.centred)
    assert np.array_equal(cached.thresholds, fresh.thresholds)


def test_thresholds_of_the_wrong_shape_are_refused_naming_the_parameter():
    plan = RunPlan.build(scenario.load("vessel-nominal"))
    spec = next(e for e in plan.scenario.estimators if e.name == "fdi")
    model = plan.estimators["fdi"].model
    with pytest.raises(ParameterError, match=r"thresholds: expected 8 rows of 3 values, got \(1, 2\)"):
        estimators.create("cofd", model, {**spec.params, "thresholds": [[1.0, 2.0]]}, 0.1)


@pytest.mark.parametrize("threads", [2, 4])
def test_a_design_is_the_same_whatever_the_blas_threads(threads, monkeypatch):
    """OpenBLAS splits a large product among its threads (one per core by default) and the split
    moves its last bits: the vessel diagnosis's discretized observers and rotating-frame gains
    differed in them, and its frames with them, between one BLAS thread and two (a machine with
    another core count logged other frames). A plan, and an estimator a node builds from its
    design, are computed on one BLAS thread: the same numbers whatever the caller's threads."""
    from threadpoolctl import threadpool_limits

    monkeypatch.setenv("COSIM_CACHE_DIR", "off")

    def design(limit: int) -> dict:
        with threadpool_limits(limits=limit, user_api="blas"):
            estimator = RunPlan.build(scenario.load("vessel-fault-T3")).estimators["fdi"]
            params = {**dataclasses.asdict(estimator.params), **estimator.node_params()}  # as the runner sends it
            spec = SimpleNamespace(kind="cofd", model=estimator.model, params=params)
            rebuilt = node._create(estimators.create, replace_sample_time(spec, estimator.sample_time), "fdi")
        return {
            "design": estimator.node_params(),
            "discrete": estimator.discrete,
            "gains": estimator.frame.gains,
            "node's discrete": rebuilt.discrete,  # what a node derives from the design it is given
        }

    one, more = design(1), design(threads)
    for name in one:
        np.testing.assert_equal(more[name], one[name], err_msg=name)


def replace_sample_time(spec: SimpleNamespace, sample_time: float | None) -> SimpleNamespace:
    spec.sample_time = sample_time
    return spec


NODE_BUILD = """
import hashlib, pickle, sys
from types import SimpleNamespace
import estimators
from cosim.run import node
from estimators import LinearModel
given = pickle.load(open(sys.argv[1], "rb"))
model = LinearModel.from_dict(given.pop("model"))
spec = SimpleNamespace(**given, model=model)
built = node._create(estimators.create, spec, "fdi")
print(hashlib.sha256(pickle.dumps((built.discrete, built.frame.gains))).hexdigest())
"""


@pytest.mark.slow
def test_a_node_process_builds_the_same_estimator_whatever_its_blas_threads(tmp_path, monkeypatch):
    """A node process loads SciPy's OpenBLAS only while it builds its estimator (a lazy import),
    after a limit on the libraries loaded so far would have been set: ``one_thread`` loads it first.
    The vessel diagnosis a node builds under OPENBLAS_NUM_THREADS=4 is the one it builds under 1."""
    import os
    import pickle

    monkeypatch.setenv("COSIM_CACHE_DIR", "off")
    estimator = RunPlan.build(scenario.load("vessel-fault-T3")).estimators["fdi"]
    params = {**dataclasses.asdict(estimator.params), **estimator.node_params()}
    spec = tmp_path / "spec.pkl"
    given = {"kind": "cofd", "model": estimator.model.to_dict(), "params": params, "sample_time": estimator.sample_time}
    spec.write_bytes(pickle.dumps(given))
    found = {
        threads: subprocess.run(
            [sys.executable, "-c", NODE_BUILD, str(spec)],
            env={**os.environ, "OPENBLAS_NUM_THREADS": str(threads)},
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        for threads in (1, 4)
    }
    assert found[1] == found[4] and len(found[1]) == 65
