"""One self-contained HTML page of a run log: what ran, how well each estimator did, the figures of ``cosim plot``.

``cosim report FILE.mcap --out report.html`` writes a page that needs nothing else to be read: the
figures are inlined as base64 PNG, the style sheet is inline, and the page loads no script, font or
image from anywhere. It reads on a laptop and on a phone: tables fit the screen (on a phone each
row becomes a card of labelled values), figures shrink to its width, long names wrap.

The page, in the order a reader needs it (``templates/report.html.j2``, jinja2):

1. the run: scenario, description, when it ran, status, duration, seed, plant, bus, settings;
2. the faults (kind, targets, window, onset and clearance);
3. the estimators: parameters, then the error of each, |x − x̂| over the whole state (its unit,
   or the units it mixes) and per state in its own unit, then each fault's peak and recovery;
4. diagnosis (detection and isolation per fault, false alarms);
5. the figures, each with a caption saying what it shows;
6. the bus (load in %, bit rates, frames per id) and the log (topics as they are, message counts,
   folded away), then any metric this page does not know yet, so that a metric added to
   ``cosim.analysis.metrics`` shows up here.

The sections are drawn in ``report_sections`` from the run's metrics, their cells and tables are
``report_tables``'s; this module puts the page together.

Every number that has a unit carries it; names (topics, estimators, metric keys) are shown as
they are written.
"""

from __future__ import annotations

import base64
import json
import math
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cosim import __version__
from cosim.analysis import report_sections as sections
from cosim.analysis.metrics import RunMetrics
from cosim.analysis.report_tables import Page, bitrate, telling
from cosim.errors import CosimError
from cosim.extras import MissingExtra
from cosim.log.metadata import LogMetadata, ScenarioRecord
from cosim.log.reader import LogReader

if TYPE_CHECKING:
    import jinja2

#: What each figure of ``cosim plot`` shows (the file names are plot.py's).
CAPTIONS = {
    "estimates": "Every state of the plant (black) against each estimator's estimate x̂, in the state's unit; "
    "the shaded spans are the faults' windows, from their onsets (dotted).",
    "state_errors": "The estimation error x̂ − x of every estimator, one panel per state, each in its own unit.",
    "error": "The estimation error |x − x̂| over the whole state (the norm the metrics score), linear (top) and "
    "logarithmic (bottom); where the states' units differ the norm mixes them.",
    "faults": "What the faults injected, from the log's truth: the deviation added to each sensor reading, the "
    "frames that were not sent, and each actuator's effectiveness δ, with every fault's onset marked.",
    "weights": "The pseudoinverse weights per sensor: the selector s and optimizer z (TAC 2024) or the weights Γ "
    "(CDC 2016); a weight going to 0 discards its sensor.",
    "bias_effect": "|h_Γ|: the part of each observer's output injection due to the true fault (logarithmic; "
    "linear near 0, where it is 0 before the fault); it vanishes when the weights reject the fault.",
    "gamma_norm": "|Γ|: the norm of the weights of the continuous-time observers (CDC 2016).",
    "bias_estimate": "The bias estimates φ̂ against the true fault φ added to each sensor.",
    "residual": "The residual r = y − C x̂ per output and its norm (logarithmic), with every fault's window shaded.",
    "gain_estimate": "The estimated sensor effectiveness γ̂ of the reconciliation schemes against the true gain.",
    "virtual_output": "The reconciled virtual output ẑ of every scheme against the true z = H_z y, and |ẑ − z|.",
    "cofd_residuals": "Each COFD observer's residual components over their thresholds (logarithmic; above 1 the "
    "component exceeds its threshold), named by the input whose fault drives them, with fault onsets, "
    "isolations and the controller's reconfiguration.",
    "trajectory": "The true state of the closed loop against time, with fault onsets and the controller's "
    "reconfiguration, if it happened.",
    "path": "The path in the plane, y against x at equal scales: the true one (black, from the dot) and each "
    "estimator's.",
}


def metrics(path: str | Path) -> RunMetrics:
    """The log's metrics (``cosim.analysis.metrics.measure``)."""
    from cosim.analysis.metrics import measure

    return measure(path)


def report(path: str | Path, out: str | Path) -> Path:
    """Write the HTML report of one log to ``out``; returns ``out``."""
    path, out = Path(path), Path(out)
    with LogReader(path) as reader:
        meta = LogMetadata.read(reader.metadata())
    values = metrics(path)
    notes = [*values.warnings, *(f"missing: {m}" for m in values.missing)]
    figures, figure_note, series = _figures(path)
    if figure_note:
        notes.append(figure_note)
    run = meta.run
    resolved = (meta.scenario or ScenarioRecord()).resolved_json()
    scenario = (run.scenario if run else None) or path.stem
    page = Page(
        title=f"{scenario}: run report",
        lead=f"{path.name} · status {values.status}",
        description=str(resolved.get("description", "")),
        facts=_facts(meta, values),
        notes=notes,
        figures=figures,
        footer=f"cosim {__version__} · cosim report {path.name}",
    )
    given = {e.get("name"): e.get("params", {}) for e in resolved.get("estimators", [])}
    page.sections["faults"] = sections.faults(values)
    page.sections["estimators"] = sections.estimators(values, run, given, series, sections.norm_unit(series))
    page.sections["diagnosis"] = sections.diagnosis(values)
    page.sections["bus"] = sections.bus(values)
    page.sections["log"] = sections.log(values)
    page.sections["other"] = sections.other(values)
    page.sections = {name: telling(tables) for name, tables in page.sections.items()}
    html = _template().render(page=page, no_run=run is None)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(html, encoding="utf-8")
    return out


def _template() -> jinja2.Template:
    import jinja2

    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("cosim.analysis", "templates"),
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    return environment.get_template("report.html.j2")


def _facts(meta: LogMetadata, values: RunMetrics) -> list[tuple[str, str]]:
    """The run at a glance: what, when, how long, on which bus."""
    run = meta.run
    if run is None:
        return []
    bus, timing = run.bus, run.timing
    sample_time, ticks = run.sample_time or math.nan, run.ticks or 0
    facts = [("scenario", f"{run.scenario} ({run.source})")]
    if run.start_time_ns:
        when = datetime.fromtimestamp(run.start_time_ns / 1e9, UTC)
        facts.append(("started", when.strftime("%Y-%m-%d %H:%M:%S UTC")))
    facts += [
        ("status", values.status),
        ("duration", f"{ticks * sample_time:g} s: {ticks} ticks of τ = {sample_time:g} s"),
        ("seed", str(run.seed)),
        ("plant", str(run.plant)),
        ("states", ", ".join(run.states)),
        ("sensors", ", ".join(run.sensors)),
        ("actuators", ", ".join(run.actuators) or "none"),
    ]
    if run.disturbances:
        facts.append(("unknown inputs", ", ".join(run.disturbances)))
    if run.operating_point:
        facts.append(("design model", run.operating_point))
    rate = bitrate(bus.get("bitrate")).text
    data = f", data phase {bitrate(bus.get('data_bitrate')).text}" if bus.get("fd") else ""
    facts.append(
        (
            "bus",
            f"{'CAN FD' if bus.get('fd') else 'classic CAN'} at {rate}{data}, "
            f"{meta.bus.get('interface', bus.get('interface', '?'))}",
        )
    )
    facts.append(
        (
            "timing",
            timing.get("mode", "?") + (f" at {timing.get('speed'):g}×" if timing.get("mode") == "realtime" else ""),
        )
    )
    facts.append(("frames", f"{values.frames.total} on the bus, {values.frames.lost} lost"))
    settings = json.loads((meta.scenario or ScenarioRecord()).settings or "[]")
    if settings:
        facts.append(("settings", ", ".join(f"{key} = {json.dumps(value)}" for key, value in settings)))
    replay = meta.replay
    if replay:
        what = "a new estimator" if replay.new else "an estimator of the run"
        facts.append(
            (
                "replay",
                f"of {replay.log}: {replay.estimator} ({replay.kind}), {what}"
                + (f", with {sections.compact(replay.params)}" if replay.params else ""),
            )
        )
    return facts


def _figures(path: Path) -> tuple[list[dict[str, str]], str, Any]:
    """The figures of ``cosim plot``, inlined, and the series they were drawn from; or a note saying
    why there are none."""
    from cosim.analysis.plot import plot
    from cosim.analysis.series import load

    try:
        series = load(path)
    except CosimError:
        series = None
    with tempfile.TemporaryDirectory(prefix="cosim-report-") as folder:
        try:
            written = plot(path, folder, fmt="png", dpi=120)
        except MissingExtra as error:
            return [], f"no figures: {error}", series
        except CosimError as error:
            return [], f"no figures: {error}", series
        except Exception as error:  # a figure that cannot be drawn must not cost the rest of the report
            return [], f"no figures: {type(error).__name__}: {error}", series
        figures = []
        for png in written:
            kind = "cofd_residuals" if png.stem.startswith("cofd_residuals") else png.stem
            caption = CAPTIONS.get(kind, "")
            figures.append(
                {
                    "id": f"fig-{png.stem}",
                    "name": png.name,
                    "data": base64.b64encode(png.read_bytes()).decode("ascii"),
                    "caption": caption,
                }
            )
    return figures, "", series
