"""What a scenario's runs need of the optional extras (``cosim.extras``), known before any run: the
``fmi`` extra for an FMU plant, and the extras an estimator's design uses (``lmi``: the LMI designs
of IJC 2018) unless its parameters give what the design would compute. A command that runs
scenarios checks them all at once with what it needs itself (``Needs``), and so names every missing
extra in one line rather than one per failed run."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field

import estimators
from cosim.extras import EXTRAS, MissingExtra, missing_words, not_installed
from cosim.kinds import KindError
from cosim.plant.fmu_model import is_fmu
from cosim.scenario import Scenario


def scenario_extras(s: Scenario) -> dict[str, list[str]]:
    """The extras a run of ``s`` needs, each with what needs it (``an FMU plant``, ``lft-uio-sr``:
    an estimator's kind)."""
    out: dict[str, list[str]] = defaultdict(list)
    if is_fmu(s.plant.model):
        out["fmi"].append("an FMU plant")
    for spec in s.estimators:
        try:
            kind = estimators.ESTIMATORS[spec.kind]
        except KindError:  # the run says so in its own words
            continue
        for extra in kind.needs_extras(dict(spec.params or {})):
            if spec.kind not in out[extra]:
                out[extra].append(spec.kind)
    return dict(out)


@dataclass
class Needs:
    """What a command needs of the extras: ``own`` (extra → modules: its engine, its table, its
    figures) and what its scenarios need, by where they come from (a case, a campaign)."""

    feature: str
    own: dict[str, list[str]] = field(default_factory=dict)
    scenarios: dict[str, dict[str, list[str]]] = field(default_factory=lambda: defaultdict(dict))

    def add(self, where: str, s: Scenario) -> None:
        """The extras of the runs of ``s`` (``where``: a case or campaign by name)."""
        for extra, why in scenario_extras(s).items():
            self.scenarios[extra].setdefault(where, [])
            self.scenarios[extra][where] += [w for w in why if w not in self.scenarios[extra][where]]

    def add_each(self, where: str, scenarios: Iterable[Scenario]) -> None:
        """``add`` for each of ``scenarios`` (a campaign's grid points: ``Campaign.point_scenarios``)."""
        for s in scenarios:
            self.add(where, s)

    def check(self) -> str | None:
        """MissingExtra naming every missing extra at once if the command itself cannot work (its
        own extras, an FMU plant); where only a design's extra is missing (its design may be in the
        design cache, or its runs fail saying so), the warning to print, or None."""
        own = not_installed(self.own)
        of_runs = not_installed({extra: EXTRAS[extra] for extra in self.scenarios})
        hard = {**own, **{extra: m for extra, m in of_runs.items() if extra == "fmi"}}
        if hard:
            raise MissingExtra(self.feature + (f" ({self._whose(of_runs)})" if of_runs else ""), {**hard, **of_runs})
        if not of_runs:
            return None
        return (
            f"{self._whose(of_runs)} need{'s' if len(self._wheres(of_runs)) == 1 else ''} {missing_words(of_runs)}; "
            "their runs fail without it, unless their designs are in the design cache"
        )

    def _wheres(self, missing: Iterable[str]) -> list[str]:
        return list(dict.fromkeys(where for extra in missing for where in self.scenarios[extra]))

    def _whose(self, missing: dict[str, list[str]]) -> str:
        """``three-tank-gains (lpv-uio-sr, lft-uio-sr)``: each place and what of it needs them."""
        parts = []
        for where in self._wheres(missing):
            why = [w for extra in missing for w in self.scenarios[extra].get(where, [])]
            parts.append(f"{where} ({', '.join(dict.fromkeys(why))})")
        return ", ".join(parts)
