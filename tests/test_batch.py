"""Batched runs (cosim.campaign.batch): the runs of one configuration stepped together give, run for run,
exactly the metrics row each gives alone; what cannot be batched runs alone and says why."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import tomlkit

import cosim.campaign.batch as batch_module
from cosim import api
from cosim.campaign.batch import refusal, run_batch, run_together
from cosim.campaign.coordinator import batches, run_campaign
from cosim.campaign.results import NONDETERMINISTIC, rows_of
from cosim.campaign.spec import builtin_names as builtin_campaigns
from cosim.campaign.spec import load_campaign
from cosim.errors import CosimError
from cosim.run.plan import RunPlan
from cosim.scenario import apply, parse_setting
from cosim.scenario.load import builtin_names
from estimators.batched import StepEach, batch_of, check_batched

SEEDS = [3, 4, 5]


def alone(loaded, seed):
    return rows_of(api.run(loaded, None, seed=seed, in_process=True, measure=True).metrics)


@pytest.mark.parametrize("name", builtin_names())
def test_every_builtin_scenario_batched_gives_each_runs_row_alone_or_says_why_not(name):
    loaded = apply(api.load(name), [("duration", 1.0)])
    why = refusal(RunPlan.build(loaded, SEEDS[0], interface="virtual"))
    if why is not None:
        with pytest.raises(CosimError, match=f"^.*{name}.*: not batched: "):
            run_batch(loaded, SEEDS)
        assert "\n" not in why
        return
    runs = run_batch(loaded, SEEDS)
    assert [run.left for run in runs] == ["", "", ""]
    for seed, run in zip(SEEDS, runs):
        assert rows_of(run.metrics) == alone(loaded, seed), seed  # exact: every float, every status


def test_the_papers_scenarios_are_batched():
    batched = {
        name
        for name in builtin_names()
        if refusal(RunPlan.build(apply(api.load(name), [("duration", 2.0)]), 0, interface="virtual")) is None
    }
    assert {"masses-bias", "masses-faults-fd", "three-tank-reconciliation", "cdc2016-ex1", "tac2024-s2-p4"} <= batched
    assert {"uio-fault-detection", "vessel-nominal", "vessel-fault-T1-T3"} <= batched  # open and closed loops
    assert "masses-spoofing" in batched  # its attacks, SecOC and detector on the ideal bus (test_batch_bus.py)
    assert {"masses-bus-overload", "masses-pid-can"} <= batched  # an arbitrated wire (test_batch_wire.py)


@pytest.mark.parametrize(
    "scenario",
    [
        "masses-bias",
        "uio-fault-detection",
        "tac2024-s1-timevarying",
        "tac2024-s2-p4",
        "vessel-nominal",
        "vessel-fault-T2-T5",
    ],
)
def test_the_builtin_batched_steps_equal_their_single_steps_with_readings_missing(scenario):
    plan = RunPlan.build(apply(api.load(scenario), [("duration", 2.0)]), 0, interface="virtual")
    rng = np.random.default_rng(1)
    for estimator in plan.estimators.values():
        if estimator.batched([estimator]) is None:
            continue
        p, m = estimator.model.p, estimator.model.m
        y = estimator.model.y_op + 0.01 * rng.standard_normal((60, 8, p))
        u = estimator.model.u_op + rng.standard_normal((60, 8, m))
        y[10:20, 3, 0] = np.nan  # one run loses a reading for a while
        y[25, 5, :] = np.nan  # one run loses every reading for a tick
        y[30:35, :, -1] = np.nan  # every run loses one
        check_batched(lambda e=estimator: copy.deepcopy(e), y, u)


def test_check_batched_names_the_first_difference():
    plan = RunPlan.build(api.load("masses-bias"), 0, interface="virtual")
    kalman = plan.estimators["kalman"]

    class Off(type(kalman)):
        @classmethod
        def batched(cls, instances):
            batch = super().batched(instances)
            batch.x = batch.x + 1e-12  # a wrong initial state in one bit
            return batch

    def make():
        wrong = copy.deepcopy(kalman)
        wrong.__class__ = Off
        return wrong

    y = np.zeros((3, 2, kalman.model.p))
    u = np.zeros((3, 2, kalman.model.m))
    with pytest.raises(AssertionError, match=r"tick 0, run 0: x̂ .* batched, .* alone"):
        check_batched(make, y, u)


PLUGIN = '''
import numpy as np
from estimators import Estimate, Estimator
from estimators.kalman import KalmanFilter, KalmanParams


class Mine(KalmanFilter):
    """A plugin written for one run (no batched step of its own): a Kalman filter that raises at
    tick 40 where the first reading of its run was above 0.2 (so in some runs and not others)."""

    kind = "mine"
    Params = KalmanParams
    batched = Estimator.batched
    k = 0
    high = None

    def _step(self, dy, du):
        self.k += 1
        if self.high is None:
            self.high = dy[0] + self.model.y_op[0] > 0.2
        if self.high and self.k > 40:
            raise ZeroDivisionError("my bug")
        return super()._step(dy, du)
'''


def test_a_plugin_without_a_batched_step_runs_in_a_batch_and_a_run_whose_plugin_raises_ends_as_alone(tmp_path):
    (tmp_path / "mine.py").write_text(PLUGIN)
    text = (api.load("masses-bias").text).replace("duration = 30.0", "duration = 1.0")
    (tmp_path / "s.toml").write_text(text + '[[estimators]]\nname = "mine"\nkind = "mine.py:Mine"\n')
    loaded = api.load_scenario(tmp_path / "s.toml")
    plan = RunPlan.build(loaded, 0, interface="virtual")
    assert isinstance(batch_of([plan.estimators["mine"]]), StepEach)
    seeds = list(range(8))
    runs = run_batch(loaded, seeds)
    left = [run for run in runs if run.left]
    assert 0 < len(left) < len(seeds)  # some runs' plugin raised, the others went on
    assert all("estimator mine raised ZeroDivisionError: my bug" in run.left for run in left)
    for seed, run in zip(seeds, runs):
        if not run.left:
            assert rows_of(run.metrics) == alone(loaded, seed)
    # in a campaign, the runs that left are run alone: their rows say the node failed, as alone
    campaign_file = tmp_path / "c.toml"
    campaign_file.write_text(f'name = "c"\nscenario = "s.toml"\nseed = 0\nseeds = {len(seeds)}\nbus = "in-process"\n')
    campaign = load_campaign(campaign_file)
    tables = {b: run_campaign(campaign, tmp_path / f"b{b}", engine="inline", keep_logs="none", batch=b) for b in (1, 8)}
    assert 0 < tables[8].batched < len(seeds) and tables[1].batched == 0
    one, eight = (metrics(tables[b].path) for b in (1, 8))
    assert one.equals(eight)
    failed = [f for f in eight.column("estimator_failed").to_pylist() if f]
    assert len(failed) == len(seeds) - tables[8].batched and all("my bug" in f for f in failed)


def metrics(path):
    table = pq.read_table(path)
    return table.drop([c for c in (*NONDETERMINISTIC, "log") if c in table.column_names])


SWEEP = """
name = "sweep"
scenario = "masses-bias"
seed = 11
seeds = 5
bus = "in-process"
[set]
duration = 1.0
"faults[0].start" = 0.5
[[axes]]
key = "faults[0].value"
values = [0.2, 0.5]
name = "bias"
"""


def test_batches_group_runs_that_differ_in_their_plants_faults_in_index_order(tmp_path):
    (tmp_path / "c.toml").write_text(SWEEP + THRESHOLDS)
    runs = load_campaign(tmp_path / "c.toml").runs()
    found = batches(runs, None, 2)
    assert sorted(r.index for batch in found for r in batch) == [r.index for r in runs]
    for batch in found:  # the bias is the plant's own: one group per threshold (a design of the estimator)
        assert len({(repr(r.settings[-1]), r.scenario_text) for r in batch}) == 1
        assert len({repr(r.settings) for r in batch}) == 2
        assert [r.index for r in batch] == sorted(r.index for r in batch)
    assert [len(b) for b in found] == [10, 10]
    assert sorted(len(b) for b in batches(runs, 4, 2)) == [2, 2, 4, 4, 4, 4]
    assert all(len(b) == 1 for b in batches(runs, 1, 2))


THRESHOLDS = """
[[axes]]
key = "estimators[0].params.poles"
values = [[0.75, 0.8, 0.85, 0.9], [0.5, 0.55, 0.6, 0.65]]
name = "poles"
"""


def test_runs_of_other_faults_noise_and_inputs_step_together_each_as_alone(monkeypatch):
    sizes = []
    init = batch_module._Batch.__init__
    monkeypatch.setattr(
        batch_module._Batch, "__init__", lambda self, plans: sizes.append(len(plans)) or init(self, plans)
    )
    base = apply(api.load("masses-bias"), [("duration", 1.0), ("faults[0].start", 0.3)])
    members = [
        (base, 3),
        (apply(base, [("faults[0].value", 0.5)]), 3),
        (apply(base, [("faults[0].start", 0.6), ("noise[0].std", 0.01)]), 4),
        (apply(base, [("inputs[0].signal.amplitude", 2.0)]), 5),
        (apply(base, [("estimators[0].params.poles", [0.5, 0.55, 0.6, 0.65])]), 6),  # another design
        (apply(base, [("bus.timing", "arbitrated")]), 7),  # another bus: another batch
        (apply(base, [("bus.timing", "arbitrated"), ("bus.fd", True), ("bus.authentication", "secoc")]), 9),  # alone
        (base, 8),
    ]
    runs = run_together(members)
    assert sizes == [5, 1, 1]  # the poles are a design of the estimator's, the wire the bus's: other batches
    assert [bool(run.refused) for run in runs] == [False] * 6 + [True, False]
    assert runs[6].refused == "its frames are authenticated (SecOC) on an arbitrated wire"
    for (loaded, seed), run in zip(members, runs):
        if not run.refused:
            assert run.seed == seed and not run.left
            assert rows_of(run.metrics) == alone(loaded, seed), seed


def test_a_batched_campaign_resumed_after_losing_runs_gives_the_same_table(tmp_path):
    (tmp_path / "c.toml").write_text(SWEEP)
    campaign = load_campaign(tmp_path / "c.toml")
    whole = run_campaign(campaign, tmp_path / "whole", engine="inline", keep_logs="none")
    assert whole.batched == whole.runs == 10
    parts = sorted((tmp_path / "whole" / "parts").glob("run-*.json"))
    for part in parts[3:8]:  # a coordinator killed mid-way: these runs never came back
        part.unlink()
    (tmp_path / "whole" / "results.parquet").unlink()
    resumed = run_campaign(campaign, tmp_path / "whole", engine="inline", keep_logs="none", resume=True)
    assert resumed.resumed == 5 and resumed.batched == 5
    one = run_campaign(campaign, tmp_path / "one", engine="inline", keep_logs="none", batch=1)
    assert metrics(resumed.path).equals(metrics(one.path))


@pytest.mark.slow
def test_a_dask_cluster_of_two_workers_with_batches_gives_the_table_of_one_worker(tmp_path):
    (tmp_path / "c.toml").write_text(SWEEP)
    campaign = load_campaign(tmp_path / "c.toml")
    two = run_campaign(campaign, tmp_path / "two", engine="dask", workers=2, keep_logs="none")
    one = run_campaign(campaign, tmp_path / "one", engine="dask", workers=1, keep_logs="none", batch=1)
    assert two.batched == 10 and one.batched == 0
    assert metrics(two.path).equals(metrics(one.path))


def test_runs_whose_log_is_kept_run_alone_and_the_campaign_says_why(tmp_path):
    (tmp_path / "c.toml").write_text(SWEEP.replace("seeds = 5", "seeds = 2"))
    result = run_campaign(load_campaign(tmp_path / "c.toml"), tmp_path / "o", engine="inline", keep_logs="all")
    assert result.batched == 0 and len(list((tmp_path / "o" / "logs").glob("*.mcap"))) == 4
    assert result.alone == {"its log is kept (--keep-logs all)": 4}
    wired = SWEEP.replace('"masses-bias"', '"masses-bus-overload"').replace("seeds = 5", "seeds = 2")
    secured = wired.replace("duration = 1.0\n", 'duration = 1.0\n"bus.fd" = true\n"bus.authentication" = "secoc"\n')
    (tmp_path / "s.toml").write_text(secured.split("[[axes]]")[0])
    result = run_campaign(load_campaign(tmp_path / "s.toml"), tmp_path / "s", engine="inline", keep_logs="none")
    assert result.alone == {"its frames are authenticated (SecOC) on an arbitrated wire": 2}


def smaller(name, folder):
    """The built-in campaign with each axis cut to its first two values, 2 seeds, 2 s runs."""
    document = tomlkit.parse(load_campaign(name).text)
    for axis in document.get("axes", []):
        for key in ("values", "labels"):
            if key in axis:
                axis[key] = list(axis[key])[:2]
    path = folder / f"{name}.toml"
    path.write_text(tomlkit.dumps(document))
    return load_campaign(path, seeds=2, settings=[parse_setting("duration=2.0")])


@pytest.mark.slow
@pytest.mark.parametrize("name", builtin_campaigns())
def test_every_builtin_campaign_batched_gives_the_table_of_its_runs_one_at_a_time(tmp_path, name):
    campaign = smaller(name, tmp_path)
    assert campaign.size >= 2
    tables = {
        b: run_campaign(campaign, tmp_path / f"b{b}", engine="inline", keep_logs="none", batch=b) for b in (1, None)
    }
    assert metrics(tables[1].path).equals(metrics(tables[None].path))


def test_the_thrust_allocations_batched_step_equals_its_single_steps_through_a_fault_report():
    plan = RunPlan.build(apply(api.load("vessel-fault-T1"), [("duration", 2.0)]), 0, interface="virtual")
    controller = plan.controller
    runs = 4
    alone = [copy.deepcopy(controller) for _ in range(runs)]
    batch = type(controller).batched([copy.deepcopy(controller) for _ in range(runs)])
    rng = np.random.default_rng(2)
    model = controller.model
    for k in range(120):
        y = model.y_op + 0.05 * rng.standard_normal((runs, model.p))
        y[1, 2] = np.nan if k % 7 == 3 else y[1, 2]  # a heading reading that did not arrive
        t = 170.0 + k * controller.sample_time  # reconfigurations are allowed from 180 s
        reports = [{"fault_mask": float(1 if r == 2 and k >= 40 else 0)} for r in range(runs)]
        u, diagnostics = batch.step(y, t, reports)
        for r, single in enumerate(alone):
            command = single.step(y[r], t, reports[r])
            assert np.array_equal(u[r], command.u), (k, r)
            for name, value in command.diagnostics.items():
                assert diagnostics[name][r] == value, (k, r, name)
    assert alone[2].law.active_mask == 1 and alone[0].law.active_mask == 0  # run 2 reconfigured, the others not


def test_a_plugins_faults_and_observer_from_the_template_run_in_a_batch_as_alone(tmp_path):
    """The plugin template (examples/plugin): its observer and its sensor fault, and an actuator
    fault of a user's file, written for one run, in a batch (each instance by itself)."""
    import shutil

    shutil.copy(Path(__file__).resolve().parent.parent / "examples" / "plugin" / "my_observer.py", tmp_path)
    (tmp_path / "my_faults.py").write_text(
        "from dataclasses import dataclass\n\nimport numpy as np\n\nfrom cosim.api import ActuatorFault\n\n\n"
        "@dataclass\nclass Reversed(ActuatorFault):\n    kind = 'reversed'\n\n    def factors(self, t, n):\n"
        "        delta = np.ones(n)\n        if self.active(t):\n            delta[list(self.channels)] = -1.0\n"
        "        return delta\n"
    )
    text = api.load("masses-bias").text.replace("duration = 30.0", "duration = 1.5")
    text += (
        '[[faults]]\nkind = "my_observer.py:Quantized"\nsensors = ["x2"]\nstart = 0.5\nparams = { step = 0.01 }\n'
        '[[faults]]\nkind = "my_faults.py:Reversed"\nactuators = ["force"]\nstart = 0.8\n'
        '[[estimators]]\nname = "template"\nkind = "my_observer.py:ResidualObserver"\n'
    )
    (tmp_path / "s.toml").write_text(text)
    loaded = api.load_scenario(tmp_path / "s.toml")
    runs = run_batch(loaded, SEEDS)
    assert [run.left for run in runs] == ["", "", ""]
    for seed, run in zip(SEEDS, runs):
        assert rows_of(run.metrics) == alone(loaded, seed)


def test_a_campaign_on_a_reference_fmu_plant_runs_alone_and_says_why(tmp_path):
    """The Modelica Association's VanDerPol (FMI 3.0) as the plant runs in a process of its own: the
    batch refuses it in one line and the campaign's runs go alone, with the table of --batch 1."""
    scenario = Path(__file__).resolve().parent / "data" / "fmus" / "vanderpol-bias.toml"
    (tmp_path / "c.toml").write_text(
        f'name = "vdp"\nscenario = "{scenario}"\nseed = 2\nseeds = 2\nbus = "in-process"\n[set]\nduration = 1.0\n'
    )
    campaign = load_campaign(tmp_path / "c.toml")
    chosen = run_campaign(campaign, tmp_path / "chosen", engine="inline", keep_logs="none")
    assert chosen.batched == 0 and chosen.alone == {"its plant is an FMU, which runs in a process of its own": 2}
    one = run_campaign(campaign, tmp_path / "one", engine="inline", keep_logs="none", batch=1)
    assert metrics(chosen.path).equals(metrics(one.path))


def test_the_disturbances_of_a_batchs_runs_are_each_runs_alone_whatever_their_seas():
    from cosim.run.loop import PlantSource
    from cosim.scenario import load

    base = load("vessel-nominal")
    calm = apply(
        base, [("disturbances", [{"input": "b_x", "signal": {"kind": "sine", "amplitude": 5.0, "frequency": 0.1}}])]
    )
    rough = apply(base, [("disturbances[0].params", {"current": 144.0, "wave_force": 108.0, "wave_moment": 108.0})])
    sine = {"input": "b_x", "signal": {"kind": "sine", "amplitude": 5.0, "frequency": 0.1}}
    both = apply(base, [("disturbances", [*base.scenario.model_dump()["disturbances"], sine])])
    for members in (
        [(base, 1), (rough, 2), (both, 3)],  # seas of one kind, together
        [(base, 1), (calm, 2), (rough, 3)],  # a run without a sea: each by itself
    ):
        sources = [PlantSource(RunPlan.build(loaded, seed, interface="virtual")) for loaded, seed in members]
        disturbance = PlantSource.disturbances_of(sources)
        for t in (0.0, 0.1, 17.3, 250.0):
            for rows in (np.arange(3), np.array([0, 2]), np.array([], dtype=int)):
                found = disturbance(rows, t)
                expected = np.array([sources[r].disturbance(t) for r in rows.tolist()]).reshape(len(rows), 3)
                np.testing.assert_array_equal(found, expected)  # bit for bit


def test_in_a_stream_a_campaign_with_enough_work_after_it_is_not_cut_for_the_workers(tmp_path):
    """A campaign's one group is cut in two for two workers only where nothing after it fills the
    second: a campaign followed by more ticks runs as one batch, the last in two; a campaign
    followed by fewer ticks than it brings is cut as when it runs alone."""
    from cosim.campaign.coordinator import _idle_workers, _Pending, run_campaigns
    from cosim.campaign.engine import InlineEngine

    class Recording(InlineEngine):
        workers = 2

        def results(self, function, items, *args):
            return super().results(function, (seen.append(item) or item for item in items), *args)

    seen: list = []
    (tmp_path / "a.toml").write_text(SWEEP.replace("seeds = 5", "seeds = 2"))
    (tmp_path / "b.toml").write_text(SWEEP.replace('name = "sweep"', 'name = "b"').replace("seeds = 5", "seeds = 3"))
    first, second = load_campaign(tmp_path / "a.toml"), load_campaign(tmp_path / "b.toml")
    members = [(first, tmp_path / "a", False), (second, tmp_path / "b", False)]
    run_campaigns(members, Recording(), keep_logs="none")
    assert [(Path(folder).name, len(specs)) for folder, specs in seen] == [("a", 4), ("b", 3), ("b", 3)]
    pendings = [_Pending(c, tmp_path / f"{name}2", False, None) for c, name in ((second, "b"), (first, "a"))]
    assert [p.ticks for p in pendings] == [6 * 100, 4 * 100]
    assert _idle_workers(pendings, 0, 2) == 2  # 400 ticks after its 600: b is cut as alone


def test_campaigns_on_one_engine_follow_each_other_without_a_gap_each_with_its_own_table(tmp_path):
    """``run_campaigns`` (the benchmark's cases): the second campaign's batches are submitted while
    the first's still run (its start comes before the first's end), and each table is the one the
    campaign gives by itself."""
    from cosim.campaign.coordinator import run_campaigns
    from cosim.campaign.engine import open_engine

    (tmp_path / "a.toml").write_text(SWEEP)
    (tmp_path / "b.toml").write_text(
        SWEEP.replace('name = "sweep"', 'name = "other"').replace("seed = 11", "seed = 12")
    )
    first, second = load_campaign(tmp_path / "a.toml"), load_campaign(tmp_path / "b.toml")
    events: list[tuple[str, int]] = []
    with open_engine("dask", 2) as pool:
        results = run_campaigns(
            [(first, tmp_path / "a", False), (second, tmp_path / "b", False)],
            pool,
            keep_logs="none",
            on_begin=lambda i: events.append(("begin", i)),
            on_done=lambda i, result: events.append(("done", i)),
        )
    assert events.index(("begin", 1)) < events.index(("done", 0)) < events.index(("done", 1))
    for campaign, result, name in ((first, results[0], "a1"), (second, results[1], "b1")):
        alone = run_campaign(campaign, tmp_path / name, engine="inline", keep_logs="none")
        assert result.batched == 10 and metrics(result.path).equals(metrics(alone.path))


def test_a_result_record_leaves_out_the_counts_it_does_not_know():
    """A batched run builds no frames, so its result record does not know their count: written
    without it, read back as None with no warning (it wrote "None", read as "not an integer", a
    warning the run alone had not); known counts are written as before."""
    from cosim.log.metadata import ResultRecord

    unknown = ResultRecord("completed", 10, None, 3, None)
    written = unknown.to_metadata()
    assert "frames_total" not in written and "deadline_misses" not in written and written["frames_lost"] == "3"
    warnings: list[str] = []
    assert ResultRecord.from_metadata(written, warnings) == unknown and warnings == []
    known = ResultRecord("completed", 10, 42, 3, 0)
    assert {k: known.to_metadata()[k] for k in ("ticks", "frames_total", "frames_lost", "deadline_misses")} == {
        "ticks": "10",
        "frames_total": "42",
        "frames_lost": "3",
        "deadline_misses": "0",
    }
