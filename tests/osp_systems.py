"""Running the systems of ``cosim fmu --system`` in the Open Simulation Platform's libcosim
(libcosimpy), and reading back what the testbed's own run of the scenario logged: what
tests/test_fmu_system.py compares and bench/fmu_system.py draws.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cosim.analysis.series import load


def run_libcosim(
    source: Path, ticks: int, steps_per_tick: int, outputs: dict[str, list[str]], step_size: float | None = None
) -> dict[str, dict[str, np.ndarray]]:
    """Run a system in libcosim, ``source`` an SSP archive (``from_ssp_file``) or a folder with
    ``OspSystemStructure.xml`` (``from_osp_config_file``), for ``ticks`` ticks of ``steps_per_tick``
    steps (``step_size`` in seconds: the SSP's own when None); the ``outputs`` of each component,
    row k the value after tick k (at t_k+1)."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.WARNING)
    if source.suffix == ".ssp":
        ns = None if step_size is None else round(step_size * 1e9)
        execution = CosimExecution.from_ssp_file(str(source), ns)
    else:
        execution = CosimExecution.from_osp_config_file(str(source))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    index = {info.name.decode(): info.index for info in execution.slave_infos()}
    references = {
        name: {v.name.decode(): v.reference for v in execution.slave_variables(i)} for name, i in index.items()
    }
    rows: dict[str, list[list[float]]] = {name: [] for name in outputs}
    for k in range(ticks):
        if not execution.step(steps_per_tick):
            raise RuntimeError(f"libcosim: the step of tick {k} failed")
        for name, variables in outputs.items():
            rows[name].append(observer.last_real_values(index[name], [references[name][v] for v in variables]))
    return {name: dict(zip(outputs[name], np.array(rows[name], dtype=float).reshape(ticks, -1).T)) for name in outputs}


def logged_estimates(log: Path) -> dict[str, dict[str, np.ndarray]]:
    """Each estimator's logged estimate and diagnostics (as its frames carried them), signal by
    signal, tick by tick."""
    found = {}
    for name, series in load(log).estimators.items():
        ticks = sorted(series.values)
        assert ticks == list(range(len(ticks)))
        found[name] = {signal: np.array([series.values[k][signal] for k in ticks]) for signal in series.values[0]}
    return found


def differences(computed: dict[str, np.ndarray], logged: dict[str, np.ndarray]) -> dict[str, int]:
    """For each logged signal, at how many ticks ``computed`` differs from it (NaN equals NaN)."""
    return {
        signal: int(np.count_nonzero(~((computed[signal] == values) | (np.isnan(computed[signal]) & np.isnan(values)))))
        for signal, values in logged.items()
    }
