"""``cosim fmu --system``: a scenario as a system of FMI 2.0 FMUs (an SSP archive and
OspSystemStructure.xml) that the Open Simulation Platform's libcosim runs, against the testbed's
own in-process run of the scenario: every estimator's estimate and diagnostics at every tick equal
to what its node logged, bit for bit (the FMUs carry the bus's quantization: masses-bias is on
classic CAN), and the plant's states equal to the run's. An open loop (masses-bias, three-tank) and
a closed one (the vessel with a thruster fault, its controller an FMU of its own, the system at
half the sample time). FMPy's SSP support runs it too, except for its first step (below), and a
scenario whose bus a system cannot express is refused in one line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosim import scenario
from cosim.cli import main
from cosim.run import fmu_ssp, fmu_system, run
from tests.conftest import ROOT
from tests.osp_systems import differences, logged_estimates, run_libcosim
from tests.test_fmu import truth

pytest.importorskip("fmpy", reason="the 'fmi' extra (FMPy) is not installed")
pytest.importorskip("libcosimpy", reason="libcosimpy (a test dependency) is not installed")


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A built-in scenario cut to ``duration`` (and to the estimators named, if any), run
    in-process and exported with ``cosim fmu --system --fmi 2``, once per module: (scenario, log,
    folder)."""
    made: dict[tuple[str, float], tuple[scenario.LoadedScenario, Path, Path]] = {}

    def get(name: str, duration: float, estimators: tuple[str, ...] = ()) -> tuple[scenario.LoadedScenario, Path, Path]:
        if (name, duration) not in made:
            loaded = scenario.apply(scenario.load(name), [("duration", duration)])
            folder = tmp_path_factory.mktemp(Path(name).stem)
            log, system = folder / "run.mcap", folder / "system"
            if estimators:
                kept = [e for e in loaded.scenario.estimators if e.name in estimators]
                loaded = scenario.LoadedScenario(
                    loaded.scenario.model_copy(update={"estimators": kept}), loaded.source, loaded.text
                )
                fmu_ssp.export(loaded, system, 2)
            else:
                command = ["fmu", name, "--set", f"duration={duration}", "--system", "--fmi", "2", "--out", str(system)]
                assert main(command) == 0
            assert run(loaded, log, interface="virtual").status == "completed"
            made[(name, duration)] = loaded, log, system
        return made[(name, duration)]

    return get


def assert_reproduces_the_run(loaded: scenario.LoadedScenario, log: Path, source: Path, steps_per_tick: int) -> None:
    """The system at ``source`` run in libcosim gives every logged estimate at every tick, and the
    plant's states are the run's."""
    s = loaded.scenario
    logged = logged_estimates(log)
    outputs = {name: list(signals) for name, signals in logged.items()}
    outputs["plant"] = [f"state.{name}" for name in s.states]
    computed = run_libcosim(source, s.ticks, steps_per_tick, outputs)
    for name, signals in logged.items():  # row k: the answer to tick k, at t_k+1
        assert differences(computed[name], signals) == dict.fromkeys(signals, 0), name
    x = truth(log)["x"]  # x_k, logged at tick k; the plant's outputs after tick k are x_k+1
    states = np.column_stack([computed["plant"][f"state.{name}"] for name in s.states])
    assert np.array_equal(states[:-1], x[1:])


@pytest.mark.slow  # a run, an export and two libcosim runs
def test_masses_bias_in_libcosim_from_its_ssp_archive_and_its_osp_file(exported):
    loaded, log, system = exported("masses-bias", 6.0)  # the bias from 5 s
    assert sorted(p.name for p in system.iterdir()) == [
        "OspSystemStructure.xml",
        "kalman.fmu",
        "masses-bias.ssp",
        "plant.fmu",
        "uniform.fmu",
    ]
    assert_reproduces_the_run(loaded, log, system / "masses-bias.ssp", 1)
    assert_reproduces_the_run(loaded, log, system, 1)


@pytest.mark.slow  # LMI designs (LFT-UIO-SR, Algorithm 2 of IJC 2018)
def test_three_tank_in_libcosim(exported):
    # the bias from 200 s; LFT-UIO-SR with (53) and with the gain test, and no reconciliation (the
    # LPV designs, 30 s more of cvxpy, take the same path)
    loaded, log, system = exported("three-tank-reconciliation", 202.0, ("lft", "lft_test", "raw"))
    assert sorted(p.name for p in system.glob("*.fmu")) == ["lft.fmu", "lft_test.fmu", "plant.fmu", "raw.fmu"]
    assert_reproduces_the_run(loaded, log, system, 1)


@pytest.mark.slow  # the plant's FMU runs the scenario's FMU in a host process of its own
def test_a_scenario_with_an_fmu_plant_in_libcosim(exported):
    """The plant an FMU (the Reference FMUs' FMI 3.0 VanDerPol, which libcosim could not run
    itself), inside the system's FMI 2.0 plant FMU."""
    loaded, log, system = exported(str(ROOT / "tests" / "data" / "fmus" / "vanderpol-bias.toml"), 5.0)
    assert_reproduces_the_run(loaded, log, system / "fmu-vanderpol-bias.ssp", 1)


@pytest.mark.slow  # a closed loop: the controller's FMU, the system at half the sample time
def test_the_vessel_with_a_thruster_fault_in_closed_loop_in_libcosim(exported):
    from cosim.log.reader import LogReader
    from cosim.log.topics import TruthInputs

    loaded, log, system = exported("vessel-fault-T1", 22.0)  # T1 fades from 20 s
    ssp = system / "vessel-fault-T1.ssp"
    assert_reproduces_the_run(loaded, log, ssp, 2)
    s = loaded.scenario
    commands = run_libcosim(system, s.ticks, 2, {"controller": list(s.actuators)})["controller"]
    with LogReader(log) as reader:
        logged = [list(TruthInputs.read(m).commanded.values()) for _, _, m in reader.messages([TruthInputs.TOPIC])]
    assert np.array_equal(np.column_stack([commands[a] for a in s.actuators]), np.array(logged))


@pytest.mark.slow  # FMPy's SSP master steps every FMU in Python
def test_fmpy_runs_the_ssp_archive_but_starts_every_input_at_zero(exported, tmp_path):
    """FMPy's ``simulate_ssp`` validates the SSD against SSP 1.0's schema and runs the system with
    the same fixed-step exchange as libcosim, except that it never reads the outputs after
    initialization: every input is 0.0 in the first step, so each estimator reads zeros at tick 0.
    Fed the logged bus inputs with tick 0's set to 0, the estimator's FMU gives FMPy's estimates
    bit for bit; and the plant, which reads nothing in an open loop, gives the run's sensor frames."""
    from fmpy import simulate_fmu
    from fmpy.ssp.simulation import simulate_ssp

    from cosim.run.fmu_estimator import bus_inputs

    loaded, log, system = exported("masses-bias", 6.0)
    s = loaded.scenario
    result = simulate_ssp(str(system / "masses-bias.ssp"), stop_time=s.duration, step_size=s.sample_time)
    logged = logged_estimates(log)
    t, inputs = bus_inputs(log, "kalman")
    for name in inputs:
        inputs[name][0] = 0.0
    table = np.rec.fromarrays([t, *inputs.values()], names=["time", *inputs])
    alone = simulate_fmu(str(system / "kalman.fmu"), stop_time=s.duration, output_interval=s.sample_time, input=table)
    for signal, values in logged["kalman"].items():
        ours = result[f"kalman.{signal}"][: s.ticks]
        assert np.array_equal(ours, alone[signal][1 : s.ticks + 1]), signal
        assert not np.array_equal(ours, values)  # the zeros of tick 0 stay in the filter's state
    codec = s.codec()  # classic CAN: the readings as the sensor frames carry them (1 um)
    carried = codec.carried_of([codec.sensor(name) for name in s.sensors])(truth(log)["measured"])
    sensors = np.column_stack([result[f"plant.{name}"][: s.ticks - 1] for name in s.sensors])
    assert np.array_equal(sensors, carried[1:])  # y_k+1 after tick k
    assert not np.array_equal(carried, truth(log)["measured"])


def test_a_system_step_other_than_its_own_is_refused_at_error(tmp_path):
    """A closed loop's FMUs take exactly half a sample time: a master stepping by the sample time
    would hand the plant the controller's command a tick late, so they refuse it."""
    import fmpy

    from cosim.run import fmu_export

    loaded = scenario.apply(scenario.load("vessel-fault-T1"), [("duration", 1.0)])
    system = fmu_system.build(loaded)
    assert system.step == 0.05 and [c.name for c in system.components] == ["plant", "fdi", "controller"]
    plant = next(c for c in system.components if c.name == "plant")
    fmu = fmu_export.package(plant.content, tmp_path / "plant.fmu", 2, plant.files, plant.platforms)
    messages = []
    with pytest.raises(Exception, match=r"fmi2DoStep failed with status 4 \(fatal\)"):  # pythonfmu: no fmi2Error
        fmpy.simulate_fmu(
            str(fmu),
            stop_time=0.2,
            output_interval=0.1,
            debug_logging=True,
            logger=lambda _, __, status, category, message: messages.append((status, message.decode())),
        )
    assert messages[-2] == (
        3,
        "the step size 0.1 s is not the system's step 0.05 s (half the sample time: the controller answers in a "
        "tick's first half, the plant and estimators in its second): refused",
    )


@pytest.mark.parametrize(
    ("name", "settings", "refused"),
    [
        ("masses-spoofing", [], "bus faults and attacks (spoof_x1, replay_x2)"),
        ("masses-bus-overload", [], "arbitrated timing and other nodes' traffic ([bus] timing, traffic)"),
        ("masses-bias", ["bus.fd=true", 'bus.authentication="secoc"'], "SecOC ([bus] authentication)"),
        ("masses-bias", ["bus.intrusion_detector=true"], "the intrusion detector ([bus] intrusion_detector)"),
        ("masses-bias", ["estimators[0].external=true"], "nodes started by hand (external: uniform)"),
    ],
)
def test_what_a_system_cannot_express_is_refused_in_one_line(name, settings, refused, tmp_path, capsys):
    command = ["fmu", name, "--system", "--fmi", "2", "--out", str(tmp_path / "system")]
    assert main([*command, *(a for setting in settings for a in ("--set", setting))]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: cosim fmu --system: builtin:{name} cannot be a system")
    assert refused in lines[0] and lines[0].endswith("run it with cosim run")
    assert not (tmp_path / "system").exists()


def test_the_system_options_are_checked_in_one_line(tmp_path, capsys):
    taken = tmp_path / "taken"
    taken.write_text("")
    cases = [
        (
            ["--system", "--estimator", "kalman"],
            "--system exports every estimator of the scenario: leave out --estimator",
        ),
        (["--system", "--out", str(taken)], f"--out {taken} is a file: with --system it is the folder to write"),
        (
            ["--system", "--set", 'estimators[0].name="plant"'],
            "estimator 'plant' has the name of the system's plant component: rename it",
        ),
    ]
    for arguments, message in cases:
        out = [] if "--out" in arguments else ["--out", str(tmp_path / "x")]
        assert main(["fmu", "masses-bias", *arguments, *out]) == 1
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and message in lines[0]


@pytest.mark.slow  # two exports of the system
def test_an_fmi3_system_holds_the_fmi2_systems_fmus_in_fmi_3(tmp_path, capsys):
    """The default, FMI 3.0 (which neither libcosim nor FMPy's SSP support runs, as the note says):
    the same components, variables and wiring, and its plant gives what the FMI 2.0 one gives."""
    import fmpy

    from tests.test_fmu_export import declared

    folders = {fmi: tmp_path / f"fmi{fmi}" for fmi in (2, 3)}
    for fmi, folder in folders.items():
        assert (
            main(["fmu", "masses-bias", "--set", "duration=1.0", "--system", "--fmi", str(fmi), "--out", str(folder)])
            == 0
        )
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "note: libcosim (the Open Simulation Platform) runs FMI 2.0 FMUs only: export with --fmi 2 for it"
    )
    assert (folders[2] / "OspSystemStructure.xml").read_text() == (folders[3] / "OspSystemStructure.xml").read_text()
    for name in ("plant", "uniform", "kalman"):
        fmus = {fmi: folder / f"{name}.fmu" for fmi, folder in folders.items()}
        assert fmpy.read_model_description(str(fmus[3])).fmiVersion == "3.0"
        assert declared(fmus[2]) == declared(fmus[3])
    results = [fmpy.simulate_fmu(str(f / "plant.fmu"), stop_time=1.0, output_interval=0.01) for f in folders.values()]
    assert all(np.array_equal(results[0][n], results[1][n]) for n in results[0].dtype.names)
