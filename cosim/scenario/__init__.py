"""Scenarios: one TOML file names the plant, timing, inputs, noise, faults, bus and estimators.

Loading validates everything that can be checked without running MuJoCo: unknown keys, wrong
types and shapes, impossible values, names that the plant does not have. All problems are
reported together in one ScenarioError, each naming its field (``faults[0].value``) and the fix.

A scalar may stand for a vector (it applies to every channel) and a number for a waveform (a
constant). Waveforms are tables with a ``kind``: constant, sine, square, ramp, exponential, sum.

The modules: ``tables`` (strict tables and error messages), ``waveforms``, ``faults`` (noise and
fault tables and the models they build), ``spec`` (the ``Scenario`` and its other tables),
``load`` (reading, checking, the built-in scenarios) and ``overrides`` (``--set KEY=VALUE``).
"""

from cosim.scenario.faults import (
    ActuatorEffectivenessSpec,
    ActuatorOffsetSpec,
    BiasSpec,
    FaultSpec,
    GainSpec,
    NoiseSpec,
    build_fault,
    build_faults,
)
from cosim.scenario.load import (
    BUILTIN_DIR,
    DEFAULT_SCENARIO,
    LoadedScenario,
    builtin_names,
    check,
    load,
    parse,
    validate,
)
from cosim.scenario.overrides import apply, load_with, parse_setting, parse_value
from cosim.scenario.spec import EstimatorSpec, Scenario, StateSpaceSpec
from cosim.scenario.waveforms import WaveformSpec, build_waveform

__all__ = [
    "BUILTIN_DIR",
    "DEFAULT_SCENARIO",
    "ActuatorEffectivenessSpec",
    "ActuatorOffsetSpec",
    "BiasSpec",
    "EstimatorSpec",
    "FaultSpec",
    "GainSpec",
    "LoadedScenario",
    "NoiseSpec",
    "Scenario",
    "StateSpaceSpec",
    "WaveformSpec",
    "apply",
    "load_with",
    "build_fault",
    "build_faults",
    "build_waveform",
    "builtin_names",
    "check",
    "load",
    "parse",
    "parse_setting",
    "parse_value",
    "validate",
]
