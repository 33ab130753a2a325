"""The data-driven baselines (``cosim.baselines``): their statistics against their definitions, the alarm's
persistence, a plant without a model refused at the first step, and a scheme that only diagnoses
publishing no estimate."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cosim import scenario
from cosim.baselines import one_class, pca
from cosim.baselines.one_class import OneClassMonitor
from cosim.baselines.pca import PcaMonitor
from estimators import LinearModel
from tests.snippets import masses

RNG = np.random.default_rng(7)


def _readings(n=2000):
    a, b = np.sin(np.linspace(0, 40, n)), np.cos(np.linspace(0, 23, n))
    clean = np.column_stack([a, b, a - b])
    return clean + 1e-3 * RNG.standard_normal(clean.shape)


def test_pca_t2_and_spe_are_their_definitions():
    x = _readings()
    fitted = pca.fit(x)
    assert len(fitted["eigenvalues"]) == 2  # x1 − x2 adds no direction of its own
    y = x[:5] + np.array([0.0, 0.3, 0.0])  # x2 biased: the correlation breaks
    z = (y - x.mean(0)) / x.std(0, ddof=1)
    _, s, vt = np.linalg.svd((x - x.mean(0)) / x.std(0, ddof=1), full_matrices=False)
    p, lam = vt[:2].T, s[:2] ** 2 / (len(x) - 1)
    stats = pca.statistics(fitted, y)
    assert stats["t2"] == pytest.approx((((z @ p) ** 2) / lam).sum(1), rel=1e-9)
    assert stats["spe"] == pytest.approx(((z - z @ p @ p.T) ** 2).sum(1), rel=1e-9)
    assert stats["spe"].min() > 100 * pca.statistics(fitted, x)["spe"].max()
    missing = pca.statistics(fitted, np.array([[0.1, np.nan, 0.2]]))
    assert missing["t2"][0] == missing["spe"][0] == np.inf


def test_the_one_class_score_is_the_mahalanobis_distance_of_values_and_changes():
    runs = [_readings(800), _readings(800)]
    fitted = one_class.fit(runs, shrinkage=0.0)
    f = one_class.features(fitted, runs[0])[1:]
    train = np.vstack([one_class.features(fitted, r)[1:] for r in runs])
    d = f - train.mean(0)
    expected = np.einsum("ij,ij->i", d, np.linalg.solve(np.cov(train, rowvar=False), d.T).T)
    assert one_class.scores(fitted, f) == pytest.approx(expected, rel=1e-6)
    assert one_class.scores(fitted, one_class.features(fitted, runs[0]))[0] == np.inf  # no change yet at the first


def _monitor(cls, fitted, persistence=3):
    model = LinearModel(
        A=np.eye(2),
        B=np.zeros((2, 1)),
        C=np.array([[1.0, 0], [0, 1], [1, -1]]),
        D=np.zeros((3, 1)),
        dt=0.01,
        states=("x1", "x2"),
        inputs=("force",),
        outputs=("x1", "x2", "x1_minus_x2"),
    )
    text = json.dumps({"kind": cls.kind_of_file, "models": [fitted]})
    return cls.from_params(model, {"fitted": text, "persistence": persistence}, 0.01)


def test_the_alarm_rises_and_falls_after_its_persistence():
    x = _readings()
    fitted = {**pca.fit(x), "sensors": ["x1", "x2", "x1_minus_x2"], "limits": {"t2": 20.0, "spe": 0.01}}
    monitor = _monitor(PcaMonitor, fitted)
    normal, faulty = x[100], x[100] + np.array([0.0, 0.5, 0.0])
    alarms = [monitor.step(y, np.zeros(1)).diagnostics["alarm"] for y in [normal, faulty, faulty, faulty, faulty]]
    assert alarms == [0.0, 0.0, 0.0, 1.0, 1.0]
    alarms = [monitor.step(normal, np.zeros(1)).diagnostics["alarm"] for _ in range(3)]
    assert alarms == [1.0, 1.0, 0.0]
    assert set(monitor.step(normal, np.zeros(1)).diagnostics) == {"t2", "spe", "alarm"}


def test_a_plant_without_a_model_fails_the_first_step_naming_it():
    fitted = {**pca.fit(_readings()), "sensors": ["y1", "y2", "y3"], "limits": {"t2": 1.0, "spe": 1.0}}
    monitor = _monitor(PcaMonitor, fitted)  # built: the run goes on; the step refuses
    with pytest.raises(LookupError, match="no model of a plant with the sensors x1, x2, x1_minus_x2"):
        monitor.step(np.zeros(3), np.zeros(1))


def test_a_scheme_that_only_diagnoses_has_no_estimate_on_the_bus():
    table = (
        '[[estimators]]\nname = "oc"\nkind = "cosim.baselines.one_class:OneClassMonitor"\n'
        'params = { model = "m.json" }\n'
    )
    s = scenario.parse(masses("t", forced=True) + table, "t.toml")
    assert OneClassMonitor.estimates is False
    codec = s.codec()
    signals = [signal for m in codec.data_messages("oc") for signal in m.signals]
    assert signals == ["d2", "alarm"]
