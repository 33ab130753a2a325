"""One self-contained HTML page of a run log: the scenario, its metrics and the figures of ``cosim plot``.

``cosim report FILE.mcap --out report.html`` writes a page that needs nothing else to be read: the
figures are inlined as base64 PNG, the style sheet is inline, and the page loads no script, font or
image from anywhere. It reads on a laptop and on a phone (viewport meta, tables that scroll
sideways on their own, figures that shrink to the screen's width).

The metrics table is built from ``cosim.analysis.metrics.compute_metrics`` (the summary of
``cosim.analysis.summary`` where that is missing) without knowing its keys: scalars become key-value rows,
a dict of records (estimators, faults, frame ids) a table with one row per record, nested records
a table of their own. A metric added there shows up here.
"""

from __future__ import annotations

import base64
import html
import json
import math
import tempfile
from pathlib import Path
from typing import Any

from cosim import __version__
from cosim.errors import CosimError
from cosim.log.metadata import LogMetadata, ScenarioRecord
from cosim.log.reader import LogReader

#: What each figure of ``cosim plot`` shows (the file names are plot.py's).
CAPTIONS = {
    "error": "Estimation error |x − x̂| of every estimator against time, linear (top) and logarithmic (bottom).",
    "weights": "Pseudoinverse weights: the selector s and optimizer z (TAC 2024) or the weights Γ (CDC 2016).",
    "bias_effect": "|h_Γ|: the part of each observer's output injection due to the true fault.",
    "gamma_norm": "|Γ|: norm of the weights of the continuous-time observers (CDC 2016).",
    "bias_estimate": "Bias estimates φ̂ against the true fault, per sensor.",
    "residual": "Residual r = y − C x̂ per output and its norm; every fault's window is shaded from its onset.",
}

_CSS = """
:root { --fg: #1b1f24; --muted: #57606a; --line: #d0d7de; --band: #f6f8fa; --accent: #0969da; --warn: #9a6700; }
* { box-sizing: border-box; }
body {
  margin: 0; font: 16px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif;
  color: var(--fg); background: #fff;
}
main { max-width: 1100px; margin: 0 auto; padding: 1rem 1.25rem 3rem; }
h1 { font-size: 1.6rem; margin: .5rem 0 .25rem; overflow-wrap: anywhere; }
h2 { font-size: 1.25rem; margin: 2rem 0 .5rem; padding-bottom: .25rem; border-bottom: 1px solid var(--line); }
h3 { font-size: 1rem; margin: 1.25rem 0 .4rem; }
p.lead { color: var(--muted); margin: 0 0 1rem; }
.notes { border-left: 4px solid var(--warn); background: #fff8c5; padding: .5rem .75rem; margin: 1rem 0; }
.notes li { overflow-wrap: anywhere; }
.scroll { overflow-x: auto; -webkit-overflow-scrolling: touch; margin: 0 0 1rem; }
table { border-collapse: collapse; font-size: .9rem; min-width: 50%; }
th, td { padding: .3rem .6rem; border-bottom: 1px solid var(--line); text-align: left; vertical-align: top; }
th { background: var(--band); font-weight: 600; white-space: nowrap; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.text { overflow-wrap: anywhere; min-width: 6rem; }
table.kv td.num { text-align: left; }
dl.settings { display: grid; grid-template-columns: max-content 1fr; gap: .2rem 1rem; margin: 0 0 1rem; }
dl.settings dt { color: var(--muted); }
dl.settings dd { margin: 0; overflow-wrap: anywhere; }
code {
  font: .85em ui-monospace, SFMono-Regular, Menlo, monospace; background: var(--band);
  padding: 0 .2em; border-radius: 3px;
}
figure { margin: 1rem 0 2rem; }
figure img { display: block; width: 100%; height: auto; border: 1px solid var(--line); }
figcaption { color: var(--muted); font-size: .9rem; margin-top: .3rem; }
footer { color: var(--muted); font-size: .8rem; margin-top: 3rem; }
@media (max-width: 640px) {
  body { font-size: 15px; }
  main { padding: .75rem .75rem 2rem; }
  h1 { font-size: 1.3rem; }
  dl.settings { grid-template-columns: 1fr; gap: 0; }
  dl.settings dd { margin-bottom: .4rem; }
  th, td { padding: .25rem .4rem; }
}
"""


def metrics(path: str | Path) -> dict[str, Any]:
    """The log's metrics (``cosim.analysis.metrics.compute_metrics``)."""
    from cosim.analysis.metrics import compute_metrics

    return compute_metrics(path)


def report(path: str | Path, out: str | Path) -> Path:
    """Write the HTML report of one log to ``out``; returns ``out``."""
    path, out = Path(path), Path(out)
    with LogReader(path) as reader:
        meta = LogMetadata.read(reader.metadata())
    values = metrics(path)
    notes = [*values.get("warnings", []), *(f"missing: {m}" for m in values.get("missing", []))]
    figures, figure_note = _figures(path)
    if figure_note:
        notes.append(figure_note)
    title = f"{(meta.run.scenario if meta.run else None) or path.stem}: run report"
    body = [
        f"<h1>{_e(title)}</h1>",
        f'<p class="lead">{_e(path.name)} · status {_e(values.get("status", "unknown"))}</p>',
    ]
    if notes:
        body.append(
            '<div class="notes" role="note"><strong>Notes</strong><ul>'
            + "".join(f"<li>{_e(n)}</li>" for n in notes)
            + "</ul></div>"
        )
    body += ['<h2 id="scenario">Scenario</h2>', _scenario(meta)]
    body += ['<h2 id="metrics">Metrics</h2>', _metrics_html(values)]
    body.append('<h2 id="figures">Figures</h2>')
    body += figures or ["<p>No figures.</p>"]
    body.append(f"<footer>cosim {_e(__version__)} · <code>cosim report {_e(path.name)}</code></footer>")
    page = (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{_e(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n<main>\n"
        + "\n".join(body)
        + "\n</main>\n</body>\n</html>\n"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(page, encoding="utf-8")
    return out


# -- sections -----------------------------------------------------------------------------------


def _scenario(meta: LogMetadata) -> str:
    """Name, description and the settings that tell runs apart, from the log's metadata."""
    run = meta.run
    if run is None:
        return "<p>The log has no <code>cosim.run</code> metadata (not written by cosim run): no scenario to show.</p>"
    resolved = (meta.scenario or ScenarioRecord()).resolved_json()
    bus, timing = run.bus, run.timing
    sample_time, ticks = run.sample_time or math.nan, run.ticks or 0
    parts = []
    if resolved.get("description"):
        parts.append(f"<p>{_e(resolved['description'])}</p>")
    settings = {
        "scenario": f"{run.scenario} ({run.source})",
        "plant": run.plant,
        "duration": f"{ticks * sample_time:g} s: {ticks} ticks of τ = {sample_time:g} s",
        "seed": run.seed,
        "sensors": ", ".join(run.sensors),
        "actuators": ", ".join(run.actuators) or "none",
        "bus": (
            f"{'CAN FD' if bus.get('fd') else 'classic CAN'} at {bus.get('bitrate', 0) / 1000:g} kbit/s"
            + (f", data phase {bus.get('data_bitrate', 0) / 1e6:g} Mbit/s" if bus.get("fd") else "")
            + f", {meta.bus.get('interface', bus.get('interface', '?'))}"
        ),
        "timing": timing.get("mode", "?")
        + (f" at {timing.get('speed'):g}×" if timing.get("mode") == "realtime" else ""),
    }
    if run.disturbances:
        settings["unknown inputs"] = ", ".join(run.disturbances)
    replay = meta.replay
    if replay:
        what = "a new estimator" if replay.new else "an estimator of the run"
        settings["replay"] = f"of {replay.log}: {replay.estimator} ({replay.kind}), {what}" + (
            f", with {_compact(replay.params)}" if replay.params else ""
        )
    parts.append(
        '<dl class="settings">' + "".join(f"<dt>{_e(k)}</dt><dd>{_e(v)}</dd>" for k, v in settings.items()) + "</dl>"
    )
    given = {e.get("name"): e.get("params", {}) for e in resolved.get("estimators", [])}
    if run.estimators:
        rows: list[list[Any]] = [
            [name, e.kind, _compact(given.get(name, {})) or "defaults"] for name, e in run.estimators.items()
        ]
        parts += ["<h3>Estimators</h3>", _table(["estimator", "kind", "parameters"], rows)]
    if run.faults:
        rows = [[f.label, f.kind, f.start, "end of run" if f.end is None else f.end] for f in run.faults]
        parts += ["<h3>Noise and faults</h3>", _table(["label", "kind", "start [s]", "end [s]"], rows)]
    return "\n".join(parts)


def _metrics_html(values: dict[str, Any]) -> str:
    shown = {k: v for k, v in values.items() if k not in ("warnings", "missing", "file")}
    return "\n".join(_sections("run", shown))


def _figures(path: Path) -> tuple[list[str], str]:
    """The figures of ``cosim plot``, inlined; or a note saying why there are none."""
    from cosim.analysis.plot import plot

    with tempfile.TemporaryDirectory(prefix="cosim-report-") as folder:
        try:
            written = plot(path, folder)
        except CosimError as error:
            return [], f"no figures: {error}"
        except Exception as error:  # a figure that cannot be drawn must not cost the rest of the report
            return [], f"no figures: {type(error).__name__}: {error}"
        figures = []
        for png in written:
            data = base64.b64encode(png.read_bytes()).decode("ascii")
            caption = CAPTIONS.get(png.stem, png.stem.replace("_", " "))
            figures.append(
                f'<figure id="fig-{_e(png.stem)}"><img src="data:image/png;base64,{data}" '
                f'alt="{_e(caption)}"><figcaption>{_e(caption)}</figcaption></figure>'
            )
    return figures, ""


# -- generic tables of nested metrics -----------------------------------------------------------


#: A mapping of more entries than this gets a table of its own rather than one cell.
_CELL_ITEMS = 6


def _leaf(value: Any) -> bool:
    """A value shown in one cell: a number, text, null, or a list or mapping of those (or empty)."""
    if isinstance(value, dict) and len(value) > _CELL_ITEMS:
        return False  # too many for one cell: a table of its own
    if isinstance(value, (dict, list)):
        return not value or all(
            not isinstance(v, (dict, list)) for v in (value.values() if isinstance(value, dict) else value)
        )
    return True


def _records(value: Any) -> bool:
    """A non-empty dict whose every value is a dict: one table row per key."""
    return isinstance(value, dict) and bool(value) and all(isinstance(v, dict) for v in value.values())


def _sections(title: str, data: dict[str, Any]) -> list[str]:
    """Scalars as a key-value table, then each nested record set or mapping as a table of its own."""
    parts = [] if title == "run" else [f"<h3>{_e(title)}</h3>"]
    scalars = [[key.replace("_", " "), value] for key, value in data.items() if _leaf(value)]
    if scalars:
        parts.append(_table(["", "value"], scalars, kind="kv"))
    for key, value in data.items():
        if _leaf(value):
            continue
        name = key if title == "run" else f"{title} · {key}"
        if _records(value):
            parts += _record_tables(name, value)
        elif isinstance(value, dict):
            parts += _sections(name, value)
        else:  # a list holding records or lists: one row each
            parts += _record_tables(
                name, {str(i): v if isinstance(v, dict) else {"value": v} for i, v in enumerate(value)}
            )
    return parts


def _record_tables(title: str, rows: dict[str, dict[str, Any]]) -> list[str]:
    """One row per record with its scalar fields as columns; nested fields as tables of their own,
    whose rows are named by the record and the nested key."""
    columns: list[str] = []
    nested: dict[str, dict[str, Any]] = {}
    for name, row in rows.items():
        for key, value in row.items():
            if _leaf(value):
                if key not in columns:
                    columns.append(key)
            else:
                nested.setdefault(key, {})[name] = value
    parts = [f"<h3>{_e(title)}</h3>"]
    if columns:
        parts.append(
            _table(
                ["", *(c.replace("_", " ") for c in columns)],
                [[name, *(row.get(c) for c in columns)] for name, row in rows.items()],
            )
        )
    for key, by_record in nested.items():
        if all(_records(v) for v in by_record.values()):
            flat = {f"{name} · {sub}": subrow for name, value in by_record.items() for sub, subrow in value.items()}
            parts += _record_tables(f"{title} · {key}", flat)
        else:
            parts += _record_tables(
                f"{title} · {key}",
                {name: value if isinstance(value, dict) else {"value": value} for name, value in by_record.items()},
            )
    return parts


def _table(header: list[str], rows: list[list[Any]], kind: str = "rows") -> str:
    """A table whose first column names the rows; ``kind`` "kv" for key-value pairs."""
    head = "".join(f'<th scope="col">{_e(h)}</th>' for h in header)
    body = "".join(
        "<tr>"
        + "".join(
            f'<th scope="row">{_e(cell)}</th>'
            if i == 0
            else f'<td class="{"num" if _numeric(cell) else "text"}">{_e(_format(cell))}</td>'
            for i, cell in enumerate(row)
        )
        + "</tr>"
        for row in rows
    )
    return (
        f'<div class="scroll"><table class="{kind}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'
    )


def _numeric(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _format(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.4g}"
    if isinstance(value, list):
        return ", ".join(_format(v) for v in value) or "none"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {_format(v)}" for k, v in value.items()) or "none"
    return str(value)


def _compact(params: dict[str, Any], limit: int = 240) -> str:
    text = ", ".join(f"{k} = {json.dumps(v)}" for k, v in params.items())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)
