"""The cells and tables of ``cosim report``'s page: numbers with their units, names as they are
written, and any mapping of metrics laid out as tables of its own (``generic``), so that a metric
the page has no section for still shows."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Cell:
    text: str
    num: bool = False


@dataclass
class Table:
    """A table of the page: its columns and its rows of cells (the first cell names the row)."""

    title: str
    columns: list[str]
    rows: list[list[Cell]]
    note: str = ""
    id: str = ""
    folded: bool = False
    """shown folded away (a <details> the reader opens)"""


@dataclass
class Page:
    title: str
    lead: str
    description: str
    facts: list[tuple[str, str]]
    notes: list[str]
    sections: dict[str, list[Table]] = field(default_factory=dict)
    figures: list[dict[str, str]] = field(default_factory=list)
    footer: str = ""


def telling(tables: list[Table]) -> list[Table]:
    """The tables that show something: a row with a value other than –, beyond the cell naming it
    (an empty table, or a table of nothing, says nothing)."""
    return [t for t in tables if any(cell.text != "–" for row in t.rows for cell in row[1:])]


def number(value: Any, unit: str = "", digits: int = 4) -> Cell:
    """A number with its unit: ``0.9185 m``; – for none."""
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return Cell(format_value(value), isinstance(value, (int, float)) and not isinstance(value, bool))
    if isinstance(value, float) and not math.isfinite(value):
        return Cell("–", True)
    text = f"{value:.{digits}g}" if isinstance(value, float) else str(value)
    return Cell(f"{text} {unit}".rstrip() if unit else text, True)


def percent(value: Any) -> Cell:
    return Cell("–", True) if value is None else Cell(f"{100 * value:.2f} %", True)


def text(value: Any) -> Cell:
    return Cell(format_value(value))


def bitrate(value: Any) -> Cell:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return Cell("–", True)
    return Cell(f"{value / 1e6:g} Mbit/s" if value >= 1e6 else f"{value / 1e3:g} kbit/s", True)


def format_value(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.4g}"
    if isinstance(value, list):
        return ", ".join(format_value(v) for v in value) or "none"
    if isinstance(value, dict):
        return ", ".join(f"{k}: {format_value(v)}" for k, v in value.items()) or "none"
    return str(value)


def unit_of_key(key: str) -> str:
    """The unit a metric's key says it has (``..._s``, ``..._per_hour``), for metrics this page does not know."""
    if key.endswith("_s") or key in ("sample_time", "fault_onset"):
        return "s"
    if key.endswith("_per_hour"):
        return "1/h"
    return ""


def value_cell(key: str, value: Any) -> Cell:
    """A metric the page does not know, by its key: a number in the unit its key says, else text."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return number(value, unit_of_key(key))
    return text(value)


def scalar_rows(values: dict[str, Any]) -> list[list[Cell]]:
    """A key-value row for each entry that is not a mapping."""
    return [[text(k), value_cell(k, v)] for k, v in values.items() if not isinstance(v, dict)]


def generic(title: str, value: dict[str, Any]) -> list[Table]:
    """A mapping of records as a table (a row per record), of scalars as key-value rows; nested
    mappings as tables of their own. A table is made only where it has cells to show: an empty
    mapping, or records with nothing but nested mappings, make none of their own."""
    tables: list[Table] = []
    if value and all(isinstance(v, dict) for v in value.values()):
        columns: list[str] = []
        for record in value.values():
            columns += [k for k, v in record.items() if not isinstance(v, dict) and k not in columns]
        rows = [[text(name)] + [value_cell(c, record.get(c)) for c in columns] for name, record in value.items()]
        if columns:
            tables.append(Table(title, ["name", *columns], rows, id=f"other-{title}"))
        for name, record in value.items():
            for key, inner in record.items():
                if isinstance(inner, dict):
                    tables += generic(f"{title} · {name} · {key}", inner)
        return tables
    if rows := scalar_rows(value):
        tables.append(Table(title, ["key", "value"], rows, id=f"other-{title}"))
    for key, inner in value.items():
        if isinstance(inner, dict):
            tables += generic(f"{title} · {key}", inner)
    return tables
