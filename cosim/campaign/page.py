"""The leaderboard as one self-contained HTML page (jinja2 template, figures inlined as PNG).

Figures: the distribution of the RMS error after onset per estimator in each group, and, for the
estimators that publish an alarm, the median detection delay against the false-alarm rate.
Outliers and failed runs link to their logs (relative to the page) where the campaign kept them.
"""

from __future__ import annotations

import base64
import io
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from markupsafe import Markup

from cosim import __version__
from cosim.campaign import wording
from cosim.campaign.leaderboard import ResultsTable, load_results
from cosim.campaign.results import Row


def _ci(value: Any, pct: bool = False) -> str:
    return wording.pct_interval(value) if pct else wording.interval(value)


def _scheme_cell(score: dict[str, Any]) -> Markup:
    """A scheme's name and its kind, each unbroken, the line breaking between them."""
    kind = score.get("kind_name") or score.get("kind") or ""
    name = Markup('<span class="nb">{}</span>').format(score["estimator"])
    return name if kind in ("", score["estimator"]) else name + Markup(' <span class="nb">({})</span>').format(kind)


def _isolated_columns(confusion: dict[str, dict[str, int]]) -> list[str]:
    """The columns of a confusion matrix: every target some fault was isolated to, sorted."""
    return sorted({found for row in confusion.values() for found in row})


def _png(fig: Any) -> str:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=130, bbox_inches="tight")
    return base64.b64encode(buffer.getvalue()).decode()


def figures(board: dict[str, Any], table: ResultsTable) -> list[dict[str, str]]:
    """The page's figures, each with its caption."""
    import matplotlib

    matplotlib.use("Agg")
    made = [_errors(board, table), _delays(board)]
    return [figure for figure in made if figure is not None]


PANELS = 12
"""At most this many groups get a panel in the figure of errors (a grid of hundreds would not read)."""


def _errors(board: dict[str, Any], table: ResultsTable) -> dict[str, str] | None:
    """The distribution of the RMS error after onset per estimator, a panel per group (the first
    ``PANELS`` groups)."""
    import matplotlib.pyplot as plt

    by = board["by"]
    found: dict[tuple[Any, ...], dict[str, list[float]]] = {}
    for values in table.rows:
        row = Row.of(values)
        error = row.rms_post_fault
        if row.status == "completed" and isinstance(error, float) and math.isfinite(error) and error > 0:
            found.setdefault(tuple(values.get(c) for c in by), {}).setdefault(str(row.estimator), []).append(error)
    panels = []
    for group in board["groups"]:
        by_estimator = found.get(tuple(group["group"].get(c) for c in by))
        if by_estimator:
            panels.append((group["group"], group.get("unit", ""), by_estimator))
    if not panels:
        return None
    shown = (
        "" if len(panels) <= PANELS else f" The first {PANELS} of {len(panels)} groups; --by fewer columns pools them."
    )
    panels = panels[:PANELS]
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 2.6 * len(panels) + 0.4), squeeze=False)
    for ax, (group, unit, data) in zip(axes[:, 0], panels):
        names = sorted(data, key=lambda k: float(np.median(data[k])))
        ax.boxplot([data[k] for k in names], orientation="horizontal", whis=(10, 90), showfliers=True)
        ax.set_yticks(range(1, len(names) + 1), names, fontsize=8)
        errors = [v for k in names for v in data[k]]
        if max(errors) > 10 * min(errors):  # errors over decades: log scale; within one, plain numbers
            ax.set_xscale("log")
        title = ", ".join(f"{k} = {v}" for k, v in group.items())
        ax.set_title(f"{title} [{unit}]" if unit else title, fontsize=9, loc="left")
        ax.grid(alpha=0.3, axis="x")
    axes[-1, 0].set_xlabel("RMS of |x − x̂| after onset (in each panel's unit)")
    fig.tight_layout()
    figure = {
        "data": _png(fig),
        "caption": "Distribution of the RMS estimation error after the fault onset, per estimator and group "
        "(box: quartiles, whiskers: 10th and 90th percentiles; log scale where they span more than a decade); "
        "best median first." + shown,
    }
    plt.close(fig)
    return figure


def _delays(board: dict[str, Any]) -> dict[str, str] | None:
    """The median detection delay (to its 90th percentile) against the false-alarm rate of each
    diagnosis scheme in each group."""
    import matplotlib.pyplot as plt

    points = [
        (g["group"], s)
        for g in board["groups"]
        for s in g["ranking"]
        if s.get("false_alarms_per_hour") is not None and s.get("detection_delay_median_s") is not None
    ]
    if not points:
        return None
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for number, (group, score) in enumerate(points):
        label = f"{score['estimator']} ({', '.join(str(v) for v in group.values())})"
        x, y = score["false_alarms_per_hour"], score["detection_delay_median_s"]
        upper = (score.get("detection_delay_p90_s") or y) - y
        ax.errorbar([x], [y], yerr=[[0.0], [upper]], fmt="o", color=f"C{number % 10}", label=label, capsize=3)
    ax.set_xlabel("false alarms per fault-free hour")
    ax.set_ylabel("detection delay [s] (median, to p90)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    figure = {
        "data": _png(fig),
        "caption": "Detection delay against false-alarm rate of the diagnosis schemes: "
        "lower left is better; the bar reaches the 90th percentile of the delay.",
    }
    plt.close(fig)
    return figure


def write_page(board: dict[str, Any], out: str | Path) -> Path:
    """Write the leaderboard page to ``out``."""
    import jinja2

    out = Path(out)
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("cosim.campaign", "templates"), autoescape=True, undefined=jinja2.StrictUndefined
    )
    environment.filters.update(
        num=wording.number,
        pct=wording.pct,
        ci=_ci,
        seconds=wording.seconds,
        rank=wording.rank,
        scheme=wording.scheme,
        scheme_cell=_scheme_cell,
        verdict=wording.verdict,
        pooled=wording.pooled,
        not_run=wording.not_run,
        group_title=wording.group_title,
        summary=wording.summary,
        isolated_columns=_isolated_columns,
    )
    sources = [Path(source) for source in board["sources"]]
    table, bundle = load_results(sources)
    for group in board["groups"]:
        group["diagnosis"] = any(s["diagnoses"] for s in group["ranking"])
    # a campaign's logs are kept beside its table; a bundle's under each case's folder, and the merged
    # rows no longer say which bundle they came from: named, not linked
    log_base = (
        None
        if bundle is not None
        else os.path.relpath(sources[0].parent.resolve(), out.parent.resolve()).replace(os.sep, "/") + "/"
    )
    name = f"{bundle['suite']} v{bundle['version']}" if bundle else board.get("campaign") or sources[0].parent.name
    page = environment.get_template("leaderboard.html.j2").render(
        board=board,
        figures=figures(board, table),
        title=f"{name}: leaderboard",
        unit=board["units"].get("rms_post_fault") or "the state's units",
        log_base=log_base,
        version=__version__,
        legend=wording.LEGEND,
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(page, encoding="utf-8")
    return out
