"""``cosim fmu``: what the exported FMUs declare (units, platforms, the refusal of a step size) and
the estimator's FMU, which FMPy fed what the node read on the bus (``bus_inputs``, from a run's
MCAP log) makes reproduce the node's logged estimates bit for bit: one estimator of each paper,
and a user's plugin.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cosim import scenario
from cosim.analysis.series import load
from cosim.bus.codec import Codec
from cosim.errors import CosimError
from cosim.log.metadata import logged_dbc
from cosim.log.reader import LogReader
from cosim.run import run
from tests.conftest import ROOT

fmpy = pytest.importorskip("fmpy", reason="the 'fmi' extra (FMPy) is not installed")
fmu_export = pytest.importorskip("cosim.run.fmu_export")
from cosim.run import fmu_estimator  # noqa: E402 (after the extra's check)

VANDERPOL_SCENARIO = ROOT / "tests" / "data" / "fmus" / "vanderpol-bias.toml"


@pytest.fixture(scope="module")
def vanderpol_fmu(tmp_path_factory):
    """The plant FMU of the VanDerPol scenario (an FMU plant with Linux binaries only)."""
    return fmu_export.export(scenario.load(str(VANDERPOL_SCENARIO)), tmp_path_factory.mktemp("fmu") / "vdp.fmu")


def test_the_plant_fmu_declares_its_units_as_fmi_units(tmp_path):
    out = fmu_export.export(scenario.load("three-tank-reconciliation"), tmp_path / "tanks.fmu")
    description = fmpy.read_model_description(str(out))
    units = {u.name: u.baseUnit for u in description.unitDefinitions}
    flow = units["cm^3/s"]  # the pumps' unit: 1 cm³/s = 1e-6 m³ s⁻¹
    assert (flow.m, flow.s, flow.kg, flow.factor, flow.offset) == (3, -1, 0, 1e-6, 0.0)
    assert (units["cm"].m, units["cm"].factor) == (1, 0.01)
    variables = [v for v in description.modelVariables if v.causality in ("input", "output")]
    assert {v.unit for v in variables} == set(units)  # every unit declared, every variable has one
    assert all("[" not in (v.description or "") for v in variables)  # not in the descriptions any more
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(out)) == []


def test_a_unit_pint_cannot_read_is_declared_by_name_alone():
    assert fmu_export.fmi_unit("furlongs per quux") == {}
    assert fmu_export.fmi_unit("degC") == {"factor": 1.0, "offset": 273.15, "base": {"K": 1}}
    assert fmu_export.fmi_unit("rad/s")["base"] == {"rad": 1, "s": -1}


def test_the_plant_fmu_declares_only_the_platforms_its_nested_fmu_has(vanderpol_fmu):
    assert fmpy.supported_platforms(str(vanderpol_fmu)) == ["linux64"]  # VanDerPol.fmu: Linux only
    with zipfile.ZipFile(vanderpol_fmu) as fmu:
        assert {Path(n).parts[1] for n in fmu.namelist() if n.startswith("binaries/")} == {"x86_64-linux"}


STATE_SPACE_FMU = ROOT / "tests" / "data" / "fmus" / "fmi3" / "StateSpace.fmu"  # inputs u start at 1 2 3
DESIGN = """
[plant.state_space]
A = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
B = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
C = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
states = ["x_1", "x_2", "x_3"]
inputs = ["u_1", "u_2", "u_3"]
outputs = ["y_1", "y_2", "y_3"]
"""


def state_space_scenario(folder: Path, fmu: Path, extra: str = "", fmu_table: str = "") -> scenario.LoadedScenario:
    path = folder / "state-space.toml"
    path.write_text(
        f'name = "state-space"\nduration = 0.1\nsample_time = 0.01\n[plant]\nmodel = "{fmu}"\n'
        f'[plant.fmu]\ninterface = "co-simulation"\n{fmu_table}\n{extra}'
    )
    return scenario.load(path)


def co_simulation_only(fmu: Path, target: Path) -> Path:
    """``fmu`` without its model-exchange interface (the element left out of its description)."""
    with zipfile.ZipFile(fmu) as old, zipfile.ZipFile(target, "w") as new:
        for item in old.infolist():
            data = old.read(item)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb"<ModelExchange[^>]*/>", b"", data)
            new.writestr(item, data)
    return target


def test_the_plant_fmu_of_an_fmu_with_a_design_model_starts_its_inputs_at_their_start_values(tmp_path):
    loaded = state_space_scenario(tmp_path, STATE_SPACE_FMU, extra=DESIGN, fmu_table='isolation = "none"')
    assert fmu_export.exported(loaded)["u_op"] == [1.0, 2.0, 3.0]  # not the design model's 0


@pytest.mark.slow  # the FMU's host processes
def test_the_plant_fmu_of_a_co_simulation_only_fmu_starts_its_inputs_at_their_start_values(tmp_path, capsys):
    from cosim.cli import main
    from cosim.plant.fmu_process import _HOSTS

    only = co_simulation_only(STATE_SPACE_FMU, tmp_path / "StateSpaceCS.fmu")
    assert fmpy.read_model_description(str(only)).modelExchange is None
    loaded = state_space_scenario(tmp_path, only)
    out = tmp_path / "plant.fmu"
    assert main(["fmu", str(loaded.source), "--out", str(out)]) == 0, capsys.readouterr().err
    assert not any(host.open for hosts in _HOSTS.by_fmu.values() for host in hosts)  # its plant closed
    inputs = [v for v in fmpy.read_model_description(str(out)).modelVariables if v.causality == "input"]
    assert [(v.name, float(v.start)) for v in inputs] == [("u_1", 1.0), ("u_2", 2.0), ("u_3", 3.0)]
    result = fmpy.simulate_fmu(str(out), stop_time=0.05, output_interval=0.01, output=["y_1", "y_2", "y_3"])
    assert tuple(result[0])[1:] == (1.0, 2.0, 3.0)  # y = x + D u with x(0) = 0 and u held at 1 2 3
    assert not any(host.open for hosts in _HOSTS.by_fmu.values() for host in hosts)  # freed at fmi3Terminate


@pytest.mark.slow  # a Python of its own
def test_the_plant_fmu_builds_under_an_ascii_locale(tmp_path):
    """pythonfmu3 reads the slave in the locale's encoding: ASCII under ``LC_ALL=C`` without
    Python's UTF-8 mode, and after an FMU's runtime called ``setlocale(LC_ALL, "C")`` in-process."""
    probe = (
        "import locale, sys\n"
        "from pathlib import Path\n"
        "from cosim import scenario\n"
        "from cosim.run import fmu_export\n"
        "assert locale.getpreferredencoding(False) == 'ANSI_X3.4-1968', locale.getpreferredencoding(False)\n"
        "fmu_export.export(scenario.load('three-tank-reconciliation'), Path(sys.argv[1]))\n"
    )
    env = dict(os.environ, LANG="C", LC_ALL="C", PYTHONUTF8="0", PYTHONPATH=str(ROOT))
    done = subprocess.run(
        [sys.executable, "-c", probe, str(tmp_path / "tanks.fmu")], env=env, capture_output=True, timeout=300
    )
    assert done.returncode == 0, done.stderr.decode("utf-8", "replace")[-2000:]
    assert fmpy.read_model_description(str(tmp_path / "tanks.fmu")).unitDefinitions


def test_the_fmu_slaves_are_ascii_and_one_that_is_not_is_refused_in_one_line(tmp_path):
    for slave in ("fmu_fmi3.py", "fmu_fmi2.py"):  # the adapters the FMUs carry
        assert fmu_export._ascii_source(Path(fmu_export.__file__).with_name(slave))
    slave = tmp_path / "slave.py"
    slave.write_text("# x\n# \u03c4\n", encoding="utf-8")
    with pytest.raises(CosimError, match=r"slave\.py line 2 is not ASCII") as error:
        fmu_export._ascii_source(slave)
    assert "\n" not in str(error.value)


def test_a_step_size_that_is_not_a_multiple_is_refused_at_error(vanderpol_fmu):
    messages = []
    with pytest.raises(Exception, match=r"fmi3DoStep failed with status 3 \(error\)"):
        fmpy.simulate_fmu(
            str(vanderpol_fmu),
            stop_time=0.1,
            output_interval=0.015,
            debug_logging=True,
            logger=lambda _, status, category, message: messages.append((status, category, message.decode())),
        )
    status, category, message = messages[-1]
    assert (status, category) == (3, b"logStatusError")  # fmi3Error
    assert message == "the step size 0.015 s is not a whole multiple of the sample time 0.01 s: refused"


def fmu_estimates(fmu: Path, log: Path, name: str, **kwargs) -> dict[str, np.ndarray]:
    """FMPy's simulation of an estimator's FMU fed what node ``name`` read on the bus (through the
    CSV file ``cosim fmu --inputs-from`` writes): each output's answer to tick k, the output at
    t_(k+1), after the step from t_k."""
    from fmpy.util import read_csv

    table = read_csv(fmu_estimator.write_bus_inputs(log, name, fmu.with_suffix(".csv")))
    t = table["time"]
    dt = t[1] - t[0]
    outputs = [v.name for v in fmpy.read_model_description(str(fmu)).modelVariables if v.causality == "output"]
    result = fmpy.simulate_fmu(
        str(fmu), stop_time=t[-1] + dt, output_interval=dt, input=table, output=outputs, **kwargs
    )
    return {o: result[o][1:] for o in outputs}


def logged_estimates(log: Path, name: str) -> dict[str, np.ndarray]:
    """The node's logged estimates and diagnostics, signal by signal, tick by tick."""
    values = load(log).estimators[name].values
    ticks = sorted(values)
    assert ticks == list(range(len(ticks)))
    return {signal: np.array([values[k][signal] for k in ticks]) for signal in values[0]}


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    """A built-in scenario cut to a duration with only one estimator (and its controller), run
    in-process once per module (the frames of the run are the same): (scenario, log)."""
    runs: dict[tuple[str, str, float], tuple[scenario.LoadedScenario, Path]] = {}

    def get(name: str, estimator: str, duration: float) -> tuple[scenario.LoadedScenario, Path]:
        if (name, estimator, duration) not in runs:
            loaded = scenario.apply(scenario.load(name), [("duration", duration)])
            spec = next(e for e in loaded.scenario.estimators if e.name == estimator)
            alone = scenario.LoadedScenario(
                loaded.scenario.model_copy(update={"estimators": [spec]}), loaded.source, loaded.text
            )
            log = tmp_path_factory.mktemp("short") / f"{name}.mcap"
            assert run(alone, log, interface="virtual").status == "completed"
            runs[(name, estimator, duration)] = alone, log
        return runs[(name, estimator, duration)]

    return get


#: One estimator of each paper (shared/papers/README.md), and the run that logs it: the session's
#: run of the built-in scenario with node processes (shared with test_reproductions.py), or a
#: shorter one in-process that still holds a fault.
PAPERS = [
    pytest.param("tac2024-s1-constant", "adaptive", None, marks=pytest.mark.slow, id="TAC2024-adaptive"),
    pytest.param("cdc2016-ex1", "L1_k1", None, marks=pytest.mark.slow, id="CDC2016-adaptive-ct"),
    pytest.param("three-tank-reconciliation", "lft", 230.0, id="IJC2018-lft-uio-sr"),  # the bias from 200 s
    pytest.param("vessel-fault-T1", "fdi", 25.0, id="CJ-cofd"),  # closed loop; T1 fades from 20 s
    pytest.param("uio-fault-detection", "uio", 11.0, id="notes-uio"),  # the sensor fault from 10 s
]


@pytest.mark.parametrize(("name", "estimator", "duration"), PAPERS)
def test_the_estimator_fmu_reproduces_the_logged_estimates_bit_for_bit(
    name, estimator, duration, builtin_run, short_run, tmp_path, monkeypatch
):
    if duration is None:
        result = builtin_run(name)
        assert result.status == "completed", result.error
        loaded, log = scenario.load(name), result.path
    else:
        loaded, log = short_run(name, estimator, duration)
    fmu = fmu_estimator.export(loaded, estimator, tmp_path / f"{estimator}.fmu")
    logged = logged_estimates(log, estimator)
    for solver in ("cvxpy", "clarabel"):  # the LMI design is frozen in: the FMU runs without them
        monkeypatch.setitem(sys.modules, solver, None)
    computed = fmu_estimates(fmu, log, estimator)
    assert sorted(computed) == sorted(logged)  # the estimate and every diagnostic, by their DBC names
    for signal, values in logged.items():  # CAN FD: float64 signals, the node's values exactly
        assert np.array_equal(computed[signal], values), signal


def test_a_plugin_estimator_travels_in_its_fmu(tmp_path):
    """examples/plugin's observer (a file kind) exports through the same path as a built-in; its
    FMU runs from another folder once the source is gone. On classic CAN the outputs are the
    estimator's values and the log holds them as the DBC's signals carry them (quantized)."""
    source = tmp_path / "source"
    shutil.copytree(ROOT / "examples" / "plugin", source)
    loaded = scenario.apply(scenario.load(str(source / "my-observer.toml")), [("bus.fd", False)])
    name = next(e.name for e in loaded.scenario.estimators if e.kind.endswith("my_observer.py:ResidualObserver"))
    log = tmp_path / "run.mcap"
    assert run(loaded, log, interface="virtual").status == "completed"
    fmu = fmu_estimator.export(loaded, name, tmp_path / "mine.fmu")
    shutil.rmtree(source)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    cwd = os.getcwd()
    os.chdir(elsewhere)
    try:
        computed = fmu_estimates(fmu, log, name)
    finally:
        os.chdir(cwd)
    with zipfile.ZipFile(fmu) as archive:
        assert "resources/plugin/my_observer.py" in archive.namelist()
    with LogReader(log) as reader:
        codec = Codec.from_dbc(logged_dbc(reader))
    logged = logged_estimates(log, name)
    carried = {signal: np.empty(len(values)) for signal, values in logged.items()}
    for spec in codec.data_messages(name):  # the bus' own arithmetic: saturated, then quantized
        for k in range(len(logged[spec.signals[0]])):
            values = [min(max(computed[s][k], c.minimum), c.maximum) for s, c in zip(spec.signals, spec.channels)]
            _, decoded = codec.encode_decoded(spec.name, k, values)
            for signal in spec.signals:
                carried[signal][k] = decoded.values[signal]
    for signal, values in logged.items():
        assert np.array_equal(carried[signal], values), signal
    assert any(not np.array_equal(computed[s], logged[s]) for s in logged)  # quantized: not the raw values


def test_a_changed_design_parameter_redoes_the_frozen_design(short_run, tmp_path):
    """The pseudoinverse observer's gain is placed at export (``node_params``) and frozen in the
    FMU; setting ``params.poles`` places it again, else the FMU would run the old gain silently."""
    import estimators

    loaded, log = short_run("tac2024-s1-constant", "uniform", 1.0)
    fmu = fmu_estimator.export(loaded, "uniform", tmp_path / "uniform.fmu")
    poles = [0.5, 0.55, 0.6, 0.65]
    messages = []
    computed = fmu_estimates(
        fmu,
        log,
        "uniform",
        start_values={"params.poles": poles},
        debug_logging=True,
        logger=lambda _, status, category, message: messages.append(message.decode()),
    )
    assert "params.poles changed: the design is redone at initialization" in messages
    content, _ = fmu_estimator.exported(loaded, "uniform")
    model = estimators.LinearModel.from_dict(content["model"])
    direct = estimators.create("pseudoinverse", model, {"poles": poles}, 0.01)
    _, inputs = fmu_estimator.bus_inputs(log, "uniform")
    table = np.column_stack(list(inputs.values()))
    expected = [direct.step(row[: model.p], row[model.p :]).x[0] for row in table]
    assert np.array_equal(computed["xhat_x1"], expected)
    assert not np.array_equal(computed["xhat_x1"], logged_estimates(log, "uniform")["xhat_x1"])


def test_the_estimator_fmu_runs_in_a_host_without_python(tmp_path):
    """A C host (tests/data/fmi_host/host.c) loads the FMU's binary as a non-Python tool does: it
    cannot without the Python library, and with it preloaded (docs/fmi.md, *Running a cosim FMU in
    other tools*) it steps the estimator as its node would."""
    import sysconfig

    import estimators

    compiler = shutil.which("cc")
    library = Path(sysconfig.get_config_var("LIBDIR") or "") / (sysconfig.get_config_var("INSTSONAME") or "")
    if compiler is None or not library.is_file():
        pytest.skip("needs a C compiler and a shared Python library")
    host = tmp_path / "host"
    headers = Path(fmpy.__file__).parent / "c-code"
    source = ROOT / "tests" / "data" / "fmi_host" / "host.c"
    subprocess.run([compiler, "-o", str(host), str(source), f"-I{headers}", "-ldl"], check=True)
    loaded = scenario.load("uio-fault-detection")
    fmu = fmu_estimator.export(loaded, "uio", tmp_path / "uio.fmu")
    unpacked = Path(fmpy.extract(str(fmu), str(tmp_path / "unpacked")))
    description = fmpy.read_model_description(str(fmu))
    refs = {v.name: str(v.valueReference) for v in description.modelVariables}
    binary = unpacked / "binaries" / "x86_64-linux" / f"{description.coSimulation.modelIdentifier}.so"
    arguments = [str(host), str(binary), str(unpacked / "resources"), description.guid, refs["y1"], refs["xhat_x1"]]
    arguments += ["5", "0.01"]
    bare = subprocess.run(arguments, capture_output=True, text=True, env={"PATH": os.environ["PATH"]})
    assert bare.returncode != 0 and "undefined symbol" in bare.stderr  # no Python in the process
    python = {"LD_PRELOAD": str(library), "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    result = subprocess.run(arguments, capture_output=True, text=True, env={"PATH": os.environ["PATH"], **python})
    # every FMI call returned and the library was unloaded; the embedded Python's shutdown at the
    # host's exit (pythonfmu3's) then crashes now and then (SIGSEGV; docs/fmi.md)
    assert result.stderr.endswith("closed\n") and result.returncode in (0, -11), result.stderr
    printed = [float(line.split()[1]) for line in result.stdout.splitlines()]
    content, _ = fmu_estimator.exported(loaded, "uio")
    node = estimators.create("uio", estimators.LinearModel.from_dict(content["model"]), content["params"], 0.01)
    expected = [node.step(np.array([1.0 + 0.01 * k, np.nan]), np.zeros(2)).x[0] for k in range(5)]
    assert printed == expected


def test_cosim_fmu_estimator_writes_the_fmu_and_its_inputs_and_refuses_in_one_line(short_run, tmp_path, capsys):
    from fmpy.util import read_csv

    from cosim.cli import main

    _, log = short_run("uio-fault-detection", "uio", 11.0)
    out = tmp_path / "uio.fmu"
    assert main(["fmu", "--estimator", "uio", "uio-fault-detection", "--out", str(out), "--inputs-from", str(log)]) == 0
    assert capsys.readouterr().err.count("wrote") == 2 and out.is_file()
    table = read_csv(out.with_suffix(".csv"))
    t, inputs = fmu_estimator.bus_inputs(log, "uio")
    assert table.dtype.names == ("time", "y1", "y2", "u1", "u2") and np.array_equal(table["time"], t)
    assert all(np.array_equal(table[n], inputs[n], equal_nan=True) for n in inputs)  # 17 digits: exact
    assert main(["fmu", "--estimator", "nope", "masses-bias", "--out", str(tmp_path / "x.fmu")]) == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: builtin:masses-bias: no estimator 'nope' (its estimators: uniform, kalman)"
    ]
    assert main(["fmu", "masses-bias", "--out", str(tmp_path / "y.fmu"), "--inputs-from", str(log)]) == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: --inputs-from needs --estimator NAME: the inputs are those of an estimator's node"
    ]


def declared(fmu: Path) -> dict[str, tuple]:
    """An FMU's variables, as FMI 2.0 names them (an FMI 3.0 array: one name per element, ``name[i]``,
    ``name[i,j]``), with what both versions declare of them: causality, variability, initial, unit,
    description and start values (as numbers; FMI 3.0's ``time`` left out, which FMI 2.0 does not require)."""
    description = fmpy.read_model_description(str(fmu))
    found = {}
    for v in description.modelVariables:
        if v.causality == "independent":
            continue
        starts = str(v.start).split() if v.start is not None else [None]
        shape = [int(d.start) for d in v.dimensions] if v.dimensions else []
        names = [f"{v.name}[{','.join(str(j + 1) for j in i)}]" for i in np.ndindex(*shape)] if shape else [v.name]
        for name, start in zip(names, starts):
            number = {"true": 1.0, "false": 0.0}.get(start, start)
            value = repr(float(number)) if start is not None and v.type != "String" else start  # NaN == NaN
            found[name] = (v.causality, v.variability, v.initial, v.unit, v.description, value)
    return found


def unit_definitions(fmu: Path) -> list[tuple]:
    """An FMU's unit definitions: each name with its SI form (None: by its name alone)."""
    fields = ("kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset")
    return [
        (u.name, None if u.baseUnit is None else [getattr(u.baseUnit, f) for f in fields])
        for u in fmpy.read_model_description(str(fmu)).unitDefinitions
    ]


def test_the_fmi2_exports_declare_what_the_fmi3_ones_do_and_give_the_same_outputs_bit_for_bit(tmp_path):
    """The plant with its faults (dropouts: NaN readings) and an estimator with array parameters,
    exported as FMI 2.0 and 3.0: the same variables, units and start values, and FMPy gives the same
    outputs from both, bit for bit, with the same inputs and with a changed parameter."""
    from fmpy.validation import validate_fmu

    loaded = scenario.apply(scenario.load("masses-faults-fd"), [("duration", 2.0), ("faults[3].start", 1.0)])
    bias = scenario.load("masses-bias")
    fmus = {}
    for fmi in (2, 3):
        fmus["plant", fmi] = fmu_export.export(loaded, tmp_path / f"plant{fmi}.fmu", fmi)
        fmus["uniform", fmi] = fmu_estimator.export(bias, "uniform", tmp_path / f"uniform{fmi}.fmu", fmi)
    for name in ("plant", "uniform"):
        assert fmpy.read_model_description(str(fmus[name, 2])).fmiVersion == "2.0"
        assert validate_fmu(str(fmus[name, 2])) == [] and validate_fmu(str(fmus[name, 3])) == []
        assert declared(fmus[name, 2]) == declared(fmus[name, 3])
        assert unit_definitions(fmus[name, 2]) == unit_definitions(fmus[name, 3])
    assert "params.poles[4]" in declared(fmus["uniform", 2])  # FMI 3.0's array, element by element
    t = np.arange(0.0, 2.0, 0.01)
    force = np.rec.fromarrays([t, np.sin(3 * t)], names=["time", "force"])
    plant = {
        fmi: fmpy.simulate_fmu(str(fmus["plant", fmi]), stop_time=2.0, output_interval=0.01, input=force)
        for fmi in (2, 3)
    }
    readings = np.rec.fromarrays(
        [t, plant[3]["x1"][:-1], plant[3]["x2"][:-1], plant[3]["x1_minus_x2"][:-1], np.sin(3 * t)],
        names=["time", "x1", "x2", "x1_minus_x2", "force"],
    )
    poles = [0.5, 0.55, 0.6, 0.65]
    runs = {
        (fmi, changed): fmpy.simulate_fmu(
            str(fmus["uniform", fmi]),
            stop_time=2.0,
            output_interval=0.01,
            input=readings,
            start_values=(
                {f"params.poles[{i + 1}]": p for i, p in enumerate(poles)} if fmi == 2 else {"params.poles": poles}
            )
            if changed
            else {},
        )
        for fmi in (2, 3)
        for changed in (False, True)
    }
    assert np.isnan(plant[3]["x2_minus_x1"]).any()  # the dropouts
    for a, b in [(plant[2], plant[3]), (runs[2, False], runs[3, False]), (runs[2, True], runs[3, True])]:
        assert a.dtype.names == b.dtype.names
        assert all(np.array_equal(a[n], b[n], equal_nan=True) for n in a.dtype.names)
    assert not np.array_equal(runs[2, False]["xhat_x1"], runs[2, True]["xhat_x1"], equal_nan=True)  # redesigned


@pytest.mark.slow  # libcosim instantiates the FMU's Python
def test_libcosim_runs_the_fmi2_plant_as_fmpy_does(tmp_path):
    """libcosim (the Open Simulation Platform) loads the FMI 2.0 plant and steps it as FMPy does,
    bit for bit; an FMI 3.0 FMU it cannot run."""
    from cosim.run.fmu_ssp import osp_system_structure
    from cosim.run.fmu_system import Component, System
    from tests.osp_systems import run_libcosim

    loaded = scenario.apply(scenario.load("masses-faults-fd"), [("duration", 1.0)])
    fmu = fmu_export.export(loaded, tmp_path / "plant.fmu", 2)
    folder = tmp_path / "alone"
    folder.mkdir()
    shutil.copy(fmu, folder / "plant.fmu")
    alone = System("alone", "", 0.01, 1.0, [Component("plant", {})], [])  # the plant, on its own
    (folder / "OspSystemStructure.xml").write_bytes(osp_system_structure(alone))
    s = loaded.scenario
    names = [*s.sensors, *(f"state.{n}" for n in s.states)]
    computed = run_libcosim(folder, s.ticks, 1, {"plant": names})["plant"]
    expected = fmpy.simulate_fmu(str(fmu), stop_time=1.0, output_interval=0.01, output=names)
    for name in names:
        assert np.array_equal(computed[name], expected[name][1:], equal_nan=True), name


def test_an_fmi2_export_refuses_a_step_and_an_integer_it_cannot_hold_in_one_line(tmp_path):
    out = fmu_export.export(scenario.load(str(VANDERPOL_SCENARIO)), tmp_path / "vdp2.fmu", 2)
    messages = []
    with pytest.raises(Exception, match=r"fmi2DoStep failed with status 4 \(fatal\)"):  # pythonfmu has no fmi2Error
        fmpy.simulate_fmu(
            str(out),
            stop_time=0.1,
            output_interval=0.015,
            debug_logging=True,
            logger=lambda _, __, status, category, message: messages.append((status, category, message.decode())),
        )
    assert messages[-2] == (
        3,
        b"logStatusError",
        "the step size 0.015 s is not a whole multiple of the sample time 0.01 s: refused",
    )
    with pytest.raises(CosimError) as error:
        fmu_export.export(scenario.apply(scenario.load("masses-bias"), [("seed", 2**31)]), tmp_path / "big.fmu", 2)
    assert str(error.value) == (
        "cosim fmu --fmi 2: seed = 2147483648 does not fit FMI 2.0's Integer (32 bits): give a smaller value "
        "(--seed, --set), or export FMI 3.0"
    )
