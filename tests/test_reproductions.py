"""The papers' case studies, run end to end (plant → faults → CAN → estimator processes → MCAP),
each checked on its log against what the paper shows (see each scenario's description)."""

from __future__ import annotations

import numpy as np
import pytest

from cosim.analysis.series import bias_effect, load
from estimators.base import DiagnosticKind
from tests.doc_figures import check, reproduction_figures, undocumented

pytestmark = pytest.mark.slow  # every test here runs node processes or long scenarios


@pytest.fixture(scope="module")
def logs(builtin_run):
    """The papers' scenarios over CAN with node processes (the session's one run of each)."""
    cache = {}

    def get(name: str):
        if name not in cache:
            result = builtin_run(name)
            assert result.status == "completed" and result.frames_lost == 0, result.error
            cache[name] = load(result.path)
        return cache[name]

    return get


def final_error(series, name, seconds=1.0):
    t, err = series.error(name)
    return float(np.sqrt(np.mean(err[t >= t[-1] - seconds] ** 2)))


def test_tac2024_s1_constant(logs):
    s = logs("tac2024-s1-constant")
    assert final_error(s, "adaptive") < 1e-8  # Fig. 3: the bias effect vanishes
    assert final_error(s, "uniform") == pytest.approx(0.9187, abs=0.01)  # steady error of eq. (19)
    _, sel = s.diagnostic("adaptive", DiagnosticKind.SELECTOR)
    _, opt = s.diagnostic("adaptive", DiagnosticKind.OPTIMIZER)
    np.testing.assert_allclose(sel[-1], opt[-2], atol=1e-9)  # s⁺ = z: the selector follows the optimizer
    np.testing.assert_allclose(np.abs(sel[-1]), np.array([3, 2, 6]) / 7, atol=1e-6)


def test_tac2024_s2_p4(logs):
    s = logs("tac2024-s2-p4")
    assert final_error(s, "residual_injection") < 1e-8  # Fig. 5: convergence with (52)-(53)
    assert final_error(s, "adaptive") > 1.0  # the selector refuses z: no convergence
    assert final_error(s, "uniform") > 0.5
    values = s.estimators["residual_injection"].values
    assert values[max(values)]["h"] == 1
    t, h = bias_effect(s, "residual_injection")
    assert h[-1] < 1e-8


def test_tac2024_s1_timevarying(logs):
    s = logs("tac2024-s1-timevarying")
    adaptive, raw, filtered = (final_error(s, n, 50.0) for n in ("adaptive", "injection", "injection_filtered"))
    assert adaptive < 1e-3 * raw  # "largely outperforms (56) without filtering"
    assert adaptive < 1.5 * filtered  # comparable to (56) with filtering (the paper reports lower; see docs/tac2024.md)
    _, sel = s.diagnostic("adaptive", DiagnosticKind.SELECTOR)
    assert np.abs(np.abs(sel[-1]) - np.array([3, 2, 6]) / 7).max() < 0.1  # near the constant case's steady state


def test_cdc2016_ex1(logs):
    s = logs("cdc2016-ex1")
    assert final_error(s, "L1_k0") > 3 and final_error(s, "L2_k0") > 5  # no allocation: error stays
    for name in ("L1_k1", "L1_k10", "L2_k1", "L2_k10"):
        assert final_error(s, name) < 0.05, name
        t, h = bias_effect(s, name)
        assert h[-1] < 0.02 * h[t >= 60.0][0], name  # h_Γ decays (Fig. 4)
    finals = np.array([s.diagnostic(n, DiagnosticKind.WEIGHT)[1][-1] for n in ("L1_k1", "L1_k10", "L2_k1", "L2_k10")])
    assert np.ptp(finals, axis=0).max() < 0.03  # about the same weights (Fig. 3)
    assert np.all(np.abs(np.linalg.norm(finals, axis=1) - 1) < 0.01)  # |Γ| ≈ 1 (Fig. 5)


def test_cdc2016_ex2(logs):
    s = logs("cdc2016-ex2")
    for name in ("L1_k1", "L2_k1"):
        _, gamma = s.diagnostic(name, DiagnosticKind.WEIGHT)
        # γ₂ → 0 (Fig. 8), to what the ±0.05 noise leaves (0.0050 measured for both gains); the
        # error back to the noise level (0.0030 and 0.0092 over the last 10 s).
        assert abs(gamma[-1][1]) < 0.01, name
        assert final_error(s, name, 10.0) < 0.015, name
    assert final_error(s, "L1_k0", 10.0) > 1 and final_error(s, "L2_k0", 10.0) > 1


@pytest.mark.parametrize("name", ["cdc2016-ex1", "cdc2016-ex2"])
def test_the_documented_figures_are_what_a_run_gives(logs, name):
    """docs/tac2024.md's figures (``python -m tests.doc_figures``) within half a unit of their last
    printed digit plus 2 %, and each printed in the document."""
    assert check(name, reproduction_figures(logs(name))) == []
    assert undocumented(name) == []
