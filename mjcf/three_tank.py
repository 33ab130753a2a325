"""The three-tank water system (Behzad et al., Int. J. Control 2018, Sec. 4, eq. (57)-(59)).

The MJCF model ``three_tank.xml`` holds the physics (flows as joints, levels as tendons, orifices as
quadratic damping; its header explains the construction). This module names its signals, lists
the parameters with their sources and gives the paper's own model, which the tests compare MuJoCo
against: the nonlinear ODE (57) with the outflow sign of tank 2 corrected (papers README, errata)
and the printed discrete-time matrices of (59).

Units. The plant's state, sensors and inputs are in the paper's units: levels in cm, pump flows
in cm^3/s, the unknown input v in cm/s (the level rate of an inflow A v into each tank, so that
E = [1 1 1]'). Inside the MJCF everything is SI (volumes in m^3, pressures in Pa); the tendons and
actuator gears convert at the boundary.

The fit (sample time, units, coefficients). The printed A and B of (59) are, to every printed
digit, exp(Ac T) and ∫₀ᵀ exp(Ac s) ds Bc with T = 1 s, levels in cm, flows in cm^3/s, and

    Ac = [[-0.0085, 0, 0.0085], [0, -0.0195, 0.0084], [0.0085, 0.0084, -0.0169]] /s,
    Bc = 0.0065 [e1 e2] cm/cm^3,

(A12 = 3.5e-5 prints as 0 at four decimals). A least-squares fit of (Ac, Bc) with the structure of
the linearized (57) to the 15 printed entries, then the interval of each parameter that keeps every
entry within half a unit of its last printed digit, gives: the three conductances 0.0085
(0.0084995-0.0085005), 0.0084 (0.0083998-0.0084008), 0.0111 (0.01107-0.01114) /s and
T/A = 0.0065 s/cm^2 (0.0065000-0.0065004). So A = 1/65 m^2 (the paper's 0.0154 m^2 to its three
digits; 0.0154 itself misses B11 by 16 half-units) and, with g = 9.81 m/s^2 and S = 5e-5 m^2, the
outflow coefficients a = conductance x A x 2 sqrt(Δh) / (S sqrt(2 g)) at Δh = 15 cm:
a1 = 0.45736, a3 = 0.45198, a2 = 0.59726 (s0 = S). Only a·sqrt(g) matters: another g rescales a.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mjcf._plant import Channel, Parameter, PlantInfo

_PAPER = "Behzad, Casavola, Tedesco & Sadrnia, Int. J. Control 2018, Sec. 4"
_FIT = "fitted to the printed A and B of eq. (59) (module docstring)"

RHO = 1000.0  # kg/m^3
G = 9.81  # m/s^2
AREA = 1.0 / 65.0  # m^2, tank cross-section
PIPE = 5e-5  # m^2, S13 = S32 = s0
A1, A3, A2 = 0.45736, 0.45198, 0.59726  # outflow coefficients of pipes 1-3, 3-2 and 2-drain
H_MAX = 62.0  # cm
Q_MAX = 100.0  # cm^3/s
SAMPLE_TIME = 1.0  # s

PARAMETERS = {
    "A": Parameter(AREA, "m^2", f"{_PAPER} (0.0154 m^2); 1/65 m^2 {_FIT}"),
    "S": Parameter(PIPE, "m^2", f"{_PAPER} (S_ij; s0 taken equal)"),
    "a1": Parameter(A1, "1", _FIT),
    "a3": Parameter(A3, "1", _FIT),
    "a2": Parameter(A2, "1", _FIT + ", with s0 = S"),
    "g": Parameter(G, "m/s^2", "standard gravity (MuJoCo's default)"),
    "rho": Parameter(RHO, "kg/m^3", "water"),
    "h_max": Parameter(H_MAX, "cm", "DTS200 tank height (Ding 2008); not in the paper"),
    "Q_max": Parameter(Q_MAX, "cm^3/s", "DTS200 pump capacity (Ding 2008); not in the paper"),
    "inertance_length": Parameter(1e-3, "m", "numerical: the flows' inertance rho l / S (three_tank.xml)"),
    "T": Parameter(SAMPLE_TIME, "s", f"sample time {_FIT}"),
}

#: The paper's operating point (Sec. 4): levels in cm, pump flows in cm^3/s.
OPERATING_LEVELS = (45.0, 15.0, 30.0)
#: The inflows the paper prints for it, "Q1 = Q2 = 0,35·10⁻⁴ m³/s"; not an equilibrium there.
PAPER_FLOWS = (35.0, 35.0)
#: The inflows that hold tanks 1 and 2 at the operating levels, Q1 = q13 and Q2 = q20 − q32 of
#: eq. (57); tank 3 has no pump and still rises 0.003 cm/s (docs/errata.md). The keyframe's ctrl.
OPERATING_FLOWS = (39.23045223843336, 12.461518500086576)

#: Eq. (59) as printed (levels in cm, flows in cm^3/s, T = 1 s).
PAPER_A = np.array([[0.9916, 0.0, 0.008393], [0.0, 0.9807, 0.008249], [0.008393, 0.008249, 0.9833]])
PAPER_B = np.array([[0.006473, 7.649e-8], [7.649e-8, 0.006437], [2.739e-5, 2.697e-5]])
PAPER_C = np.array([[10.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 1.0]])
PAPER_E = np.array([[1.0], [1.0], [1.0]])

#: Rows of the output matrix for each sensor; the paper's C is the first four, in order.
SENSOR_ROWS = {
    "h1_x10": (10.0, 0.0, 0.0),
    "h1": (1.0, 0.0, 0.0),
    "h2": (0.0, 1.0, 0.0),
    "h_sum": (1.0, 1.0, 1.0),
    "h3": (0.0, 0.0, 1.0),
}
PAPER_SENSORS = ("h1_x10", "h1", "h2", "h_sum")


def _level(name: str, description: str, scale: float = 1.0) -> Channel:
    # 1 µm quantum (10 µm for 10 h1) over a range wide enough for faulty readings.
    return Channel(name, "cm", description, -100.0 * scale, 200.0 * scale, 1e-4 * max(scale, 1.0))


INFO = PlantInfo(
    name="three_tank",
    description="Three-tank water system, pumps into tanks 1 and 2 (IJC 2018, Sec. 4; Ding 2008)",
    model_file="three_tank.xml",
    states=(
        _level("h1", "water level of tank 1"),
        _level("h2", "water level of tank 2"),
        _level("h3", "water level of tank 3 (the middle tank)"),
    ),
    sensors=(
        _level("h1_x10", "10 h1, the first row of C in eq. (59)", 10.0),
        _level("h1", "level of tank 1"),
        _level("h2", "level of tank 2"),
        _level("h_sum", "h1 + h2 + h3, the last row of C in eq. (59)", 3.0),
        _level("h3", "level of tank 3 (not among the paper's outputs)"),
        # The outputs y of eq. (58)-(59): transmitters zeroed at the operating point, reading the
        # deviation of the same quantities from it. A loss of effectiveness scales what they
        # transmit, y = Δ(γ) C (h - h_op) + F b, which is the paper's model (2) exactly.
        *(
            replace(
                _level(
                    f"y{i + 1}", f"{name} - its value at the operating point (eq. (58)-(59), output {i + 1})", scale
                ),
                minimum=-scale * 100.0,
                source=name,
                zero=float(np.dot(SENSOR_ROWS[name], OPERATING_LEVELS)),
            )
            for i, (name, scale) in enumerate((("h1_x10", 10.0), ("h1", 1.0), ("h2", 1.0), ("h_sum", 3.0)))
        ),
    ),
    actuators=(
        Channel("Q1", "cm^3/s", "pump flow into tank 1", 0.0, Q_MAX, 1e-4),
        Channel("Q2", "cm^3/s", "pump flow into tank 2", 0.0, Q_MAX, 1e-4),
    ),
    parameters=PARAMETERS,
    disturbances=(Channel("v", "cm/s", "unknown input: inflow A v into each tank (E = [1 1 1]')", -1.0, 1.0, 1e-6),),
    state_tendons=("h1", "h2", "h3"),
    drift_left_out="it is the paper's model (59), linear about a point that tank 3 leaves at 0.003 cm/s whatever the "
    "pumps do (docs/errata.md)",
)


def output_matrix(sensors: list[str] | tuple[str, ...] = PAPER_SENSORS) -> np.ndarray:
    """The output matrix for a suite of sensors, shape (len(sensors), 3); the paper's C by default."""
    return np.array([SENSOR_ROWS[name] for name in sensors])


def _flows(h: np.ndarray) -> tuple[float, float, float]:
    """Torricelli flows q13, q32, q20 in m^3/s for levels h in m (eq. (57))."""
    h1, h2, h3 = h
    q13 = A1 * PIPE * np.sign(h1 - h3) * np.sqrt(2.0 * G * abs(h1 - h3))
    q32 = A3 * PIPE * np.sign(h3 - h2) * np.sqrt(2.0 * G * abs(h3 - h2))
    q20 = A2 * PIPE * np.sqrt(2.0 * G * max(h2, 0.0))
    return q13, q32, q20


def level_rates(h: np.ndarray, q1: float, q2: float, v: float = 0.0) -> np.ndarray:
    """dh/dt of eq. (57) with the erratum (outflow of tank 2 subtracted), in the plant's units:
    levels h in cm, pump flows in cm^3/s, unknown input v in cm/s; returns cm/s."""
    q13, q32, q20 = _flows(np.asarray(h, dtype=float) / 100.0)
    inflow = np.array([q1 * 1e-6 - q13, q2 * 1e-6 + q32 - q20, q13 - q32])  # m^3/s
    return inflow / AREA * 100.0 + v


def continuous_model(h: tuple[float, float, float] = OPERATING_LEVELS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Jacobians (Ac, Bc, Ec) of eq. (57) at levels h (cm), in cm, cm^3/s and cm/s.

    Each orifice contributes its conductance dq/dΔh = q / (2 Δh); heads must be nonzero.
    """
    levels = np.asarray(h, dtype=float)
    q13, q32, q20 = _flows(levels / 100.0)
    heads = (levels[0] - levels[2], levels[2] - levels[1], levels[1])
    k13, k32, k20 = (q * 1e6 / (2.0 * dh) / (AREA * 1e4) for q, dh in zip((q13, q32, q20), heads))  # 1/s
    Ac = np.array([[-k13, 0.0, k13], [0.0, -k32 - k20, k32], [k13, k32, -k13 - k32]])
    Bc = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]) / (AREA * 1e4)
    return Ac, Bc, np.ones((3, 1))
