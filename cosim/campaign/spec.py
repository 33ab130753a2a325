"""Campaign files: a base scenario, seeds, fixed settings, axes and sampled settings, expanded into runs.

A campaign file is TOML::

    name = "masses-bias-sweep"
    scenario = "masses-bias"        # a built-in scenario, or a TOML file (relative to this file)
    seed = 0                        # the campaign seed: every run's seed and samples derive from it
    seeds = 8                       # replicates: 8 (0…7) or a list of labels
    bus = "in-process"              # or "processes": estimators in node processes over udp_multicast

    [set]                           # settings of every run (paths as in cosim run --set)
    duration = 10.0

    [[axes]]                        # a grid: every combination of every axis's values
    key = "faults[0].sensors"
    values = [["x1"], ["x2"]]
    name = "sensor"                 # the column in the results (default: the key)
    labels = ["x1", "x2"]           # optional: what the column shows for each value

    [[sample]]                      # drawn per run from the campaign seed
    key = "faults[0].start"
    distribution = "uniform"        # uniform (low, high), loguniform (low, high), choice (values)
    low = 2.0
    high = 8.0

An axis may set several paths at once (``key`` a list, each value a list with one entry per key).
Runs are numbered 0, 1, … over the grid (the first axis slowest), with the replicates innermost.

Common random numbers: a run's scenario seed depends on its replicate alone, drawn from
SeedSequence(campaign seed, spawn_key=(REPLICATE_KEY, replicate)); within a run every noise model,
fault, environment and bus fault draws from its own stream keyed by its label. So every cell of the
grid sees, replicate by replicate, the same weather, noise and random faults wherever a setting
does not change them: two estimators, two fault sizes or two thresholds are compared on the same
draws (paired), and the leaderboard tests their differences pair by pair. Run i's samples are drawn
from spawn_key=(i, 1). A run's settings and seed depend on nothing but the file and its index, so
the results do not depend on the engine, the number of workers or the order of completion.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator

import scenarios
from cosim.errors import ScenarioError
from cosim.scenario import LoadedScenario, Scenario, apply, load
from cosim.scenario.load import builtin_names as scenario_files
from cosim.scenario.load import read_toml_file
from cosim.scenario.tables import Strict, loads_toml, problem_message, problem_path

BUILTIN_DIR = Path(scenarios.__file__).resolve().parent / "campaigns"
#: Columns of the results table that every row has; axis and sample columns must not take these names.
RESERVED = ("run", "replicate", "seed", "status", "error", "wall_time_s", "estimator", "kind", "log")
#: The spawn-key group of the replicates' scenario seeds (a run's samples use (run index, 1)).
REPLICATE_KEY = 0x5EED


class AxisSpec(Strict):
    key: str | list[str]
    values: list[Any] = Field(min_length=1)
    name: str = ""
    labels: list[str] | None = None

    @model_validator(mode="after")
    def _shapes(self) -> AxisSpec:
        if self.labels is not None and len(self.labels) != len(self.values):
            raise ValueError(f"labels has {len(self.labels)} entries for {len(self.values)} values; give one per value")
        if isinstance(self.key, list):
            for value in self.values:
                if not isinstance(value, list) or len(value) != len(self.key):
                    raise ValueError(
                        f"with {len(self.key)} keys, every value is a list of {len(self.key)} (one per key)"
                    )
        return self

    @property
    def column(self) -> str:
        return self.name or (self.key if isinstance(self.key, str) else "+".join(self.key))

    def settings(self, i: int) -> list[tuple[str, Any]]:
        keys = [self.key] if isinstance(self.key, str) else self.key
        values = [self.values[i]] if isinstance(self.key, str) else self.values[i]
        return list(zip(keys, values))

    def shown(self, i: int) -> Any:
        return self.labels[i] if self.labels is not None else _cell(self.values[i])


class SampleSpec(Strict):
    key: str
    distribution: Literal["uniform", "loguniform", "choice"]
    low: float | None = None
    high: float | None = None
    values: list[Any] | None = None
    name: str = ""

    @model_validator(mode="after")
    def _parameters(self) -> SampleSpec:
        if self.distribution == "choice":
            if not self.values:
                raise ValueError("choice needs values = [...] (at least one)")
            if self.low is not None or self.high is not None:
                raise ValueError("choice takes values, not low and high")
            return self
        if self.low is None or self.high is None or self.values is not None:
            raise ValueError(f"{self.distribution} needs low and high (and no values)")
        if not self.low <= self.high:
            raise ValueError(f"low ({self.low}) must not exceed high ({self.high})")
        if self.distribution == "loguniform" and not self.low > 0:
            raise ValueError("loguniform needs low > 0")
        return self

    @property
    def column(self) -> str:
        return self.name or self.key

    def draw(self, rng: np.random.Generator) -> Any:
        if self.distribution == "choice":
            assert self.values is not None
            return self.values[int(rng.integers(len(self.values)))]
        assert self.low is not None and self.high is not None
        if self.distribution == "uniform":
            return float(rng.uniform(self.low, self.high))
        return float(math.exp(rng.uniform(math.log(self.low), math.log(self.high))))


class CampaignSpec(Strict):
    name: Annotated[str, Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")]
    description: str = ""
    scenario: str
    seed: Annotated[int, Field(ge=0)] = 0
    seeds: Annotated[int, Field(ge=1)] | Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)] = 1
    bus: Literal["in-process", "processes"] = "in-process"
    set: dict[str, Any] = {}
    axes: list[AxisSpec] = []
    sample: list[SampleSpec] = []

    @model_validator(mode="after")
    def _columns(self) -> CampaignSpec:
        columns = [a.column for a in self.axes] + [s.column for s in self.sample]
        for column in columns:
            if column in RESERVED or columns.count(column) > 1:
                raise ValueError(
                    f"two axes or samples, or one and a results column, are both named {column!r}: "
                    f"give them distinct names (name = ...)"
                )
        return self

    @property
    def replicates(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)


@dataclass(frozen=True)
class RunSpec:
    """One run of a campaign: everything a worker needs, plain and picklable."""

    index: int
    replicate: int
    seed: int
    settings: tuple[tuple[str, Any], ...]
    columns: tuple[tuple[str, Any], ...]
    """The axis and sample columns of its rows (name, value as shown)."""
    scenario_text: str
    scenario_source: str
    in_process: bool


@dataclass(frozen=True)
class Campaign:
    """A validated campaign file with its base scenario."""

    spec: CampaignSpec
    source: str
    text: str
    base: LoadedScenario

    def kept_text(self, folder: Path) -> str:
        """The text a campaign's folder keeps (``campaign.toml``): the file with the command line's
        changes, and a scenario file named relative to the folder, so that the copy is the campaign
        wherever it is loaded from (``cosim campaign DIR/campaign.toml --out DIR --resume``)."""
        if Path(self.spec.scenario).suffix != ".toml":  # a built-in scenario
            return self.text
        scenario = os.path.relpath(Path(self.base.source).resolve(), folder.resolve())
        if scenario == self.spec.scenario:
            return self.text
        import tomlkit

        document = tomlkit.parse(self.text)
        document["scenario"] = Path(scenario).as_posix()
        return tomlkit.dumps(document)

    @property
    def grid(self) -> list[tuple[int, ...]]:
        """Every combination of the axes' value indices (the first axis slowest)."""
        return list(itertools.product(*(range(len(a.values)) for a in self.spec.axes)))

    @property
    def size(self) -> int:
        return len(self.grid) * len(self.spec.replicates)

    def point_scenarios(self) -> list[Scenario]:
        """The scenario of every grid point (its first replicate's settings: an axis may change
        the plant or the estimators; a sample, drawn per run, is taken as drawn for run 0)."""
        replicate = self.spec.replicates[0]
        return [apply(self.base, list(self.run(0, point, replicate).settings)).scenario for point in self.grid]

    def runs(self) -> list[RunSpec]:
        """Every run of the campaign, in index order."""
        spec = self.spec
        out: list[RunSpec] = []
        for point in self.grid:
            for replicate in spec.replicates:
                out.append(self.run(len(out), point, replicate))
        return out

    def run(self, index: int, point: tuple[int, ...], replicate: int) -> RunSpec:
        spec = self.spec
        seed = replicate_seed(spec.seed, replicate)
        rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(index, 1)))
        settings = list(spec.set.items())
        columns: list[tuple[str, Any]] = []
        for axis, i in zip(spec.axes, point):
            settings += axis.settings(i)
            columns.append((axis.column, axis.shown(i)))
        for sample in spec.sample:
            value = sample.draw(rng)
            settings.append((sample.key, value))
            columns.append((sample.column, _cell(value)))
        return RunSpec(
            index,
            replicate,
            seed,
            tuple(settings),
            tuple(columns),
            self.base.text,
            self.base.source,
            spec.bus == "in-process",
        )


def replicate_seed(campaign_seed: int, replicate: int) -> int:
    """The scenario seed of every run of a replicate (common random numbers across the grid)."""
    return int(np.random.SeedSequence(campaign_seed, spawn_key=(REPLICATE_KEY, replicate)).generate_state(1)[0])


def _cell(value: Any) -> Any:
    """A value as a results column shows it: numbers and text as they are, anything else as JSON."""
    if isinstance(value, bool) or value is None:
        return json.dumps(value)
    return value if isinstance(value, (int, float, str)) else json.dumps(value)


def builtin_names() -> list[str]:
    return scenario_files(BUILTIN_DIR)


def load_campaign(
    name_or_path: str | Path,
    *,
    seeds: int | None = None,
    settings: Sequence[tuple[str, Any]] = (),
    only: dict[str, list[str]] | None = None,
) -> Campaign:
    """A built-in campaign by name, or a campaign file; every grid point is validated against the
    base scenario before anything runs (one error naming the field, like a scenario's).

    ``seeds`` replaces the file's, ``settings`` (``--set KEY=VALUE``) join its ``[set]``, ``only``
    keeps of an axis (by its column) the values shown as given: the campaign's text (stored in its
    folder, compared on ``--resume``) is the file so changed."""
    text, source, path = read_toml_file(str(name_or_path), BUILTIN_DIR, "campaign")
    if seeds is not None or settings or only:
        text = _changed(text, source, seeds, settings, only or {})
    try:
        data = loads_toml(text)
    except tomllib.TOMLDecodeError as error:
        raise ScenarioError(f"{source}: invalid TOML: {error}") from None
    try:
        spec = CampaignSpec.model_validate(data)
    except ValidationError as error:
        problems = [f"{problem_path(e['loc'], data)}: {problem_message(dict(e))}" for e in error.errors()]
        raise ScenarioError(f"{source}: " + ("; ".join(problems))) from None
    scenario_path = Path(spec.scenario)
    if scenario_path.suffix == ".toml" and not scenario_path.is_absolute():
        scenario_path = path.parent / scenario_path
    try:
        base = load(scenario_path if scenario_path.suffix == ".toml" else spec.scenario)
    except ScenarioError as error:
        raise ScenarioError(f"{source}: scenario: {error}") from None
    campaign = Campaign(spec, source, text, base)
    _check_settings(campaign)
    return campaign


def _changed(
    text: str, source: str, seeds: int | None, settings: Sequence[tuple[str, Any]], only: dict[str, list[str]]
) -> str:
    """The campaign file's text with the command line's seeds and settings and the axes' values
    kept (``only``), its comments kept."""
    import tomlkit
    from tomlkit.exceptions import TOMLKitError

    try:
        document = tomlkit.parse(text)
    except TOMLKitError as error:
        raise ScenarioError(f"{source}: invalid TOML: {error}") from None
    if seeds is not None:
        document["seeds"] = seeds
    if settings:
        table = document.setdefault("set", tomlkit.table())
        for key, value in settings:
            table[key] = value
    axes = {AxisSpec.model_validate(axis.unwrap()).column: axis for axis in document.get("axes", [])}
    for column, kept in only.items():
        if column not in axes:
            raise ScenarioError(f"{source}: no axis {column!r} to choose values of (axes: {', '.join(axes)})")
        axis = AxisSpec.model_validate(axes[column].unwrap())
        indices = [i for i in range(len(axis.values)) if str(axis.shown(i)) in kept]
        if len(indices) != len(kept):
            shown = ", ".join(str(axis.shown(i)) for i in range(len(axis.values)))
            raise ScenarioError(f"{source}: axis {column}: not all of {kept} are its values ({shown})")
        axes[column]["values"] = [axis.values[i] for i in indices]
        if axis.labels is not None:
            axes[column]["labels"] = [axis.labels[i] for i in indices]
    return tomlkit.dumps(document)


def _check_settings(campaign: Campaign) -> None:
    """Every grid point's settings (and one draw of the samples) make a valid scenario."""
    spec, seen = campaign.spec, set()
    for point in campaign.grid:
        if point in seen:
            continue
        seen.add(point)
        run = campaign.run(0, point, spec.replicates[0])
        try:
            apply(campaign.base, run.settings)
        except ScenarioError as error:
            where = ", ".join(f"{column} = {value}" for column, value in run.columns) or "its [set]"
            raise ScenarioError(f"{campaign.source}: the run with {where}: {error}") from None
