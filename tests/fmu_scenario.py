"""The text of a scenario whose plant is an FMU, for the FMU tests."""

from __future__ import annotations

from pathlib import Path


def scenario_text(
    fmu: Path,
    interface: str,
    *,
    duration: float,
    dt: float,
    extra: str = "",
    fmu_table: str = "",
    name: str | None = None,
) -> str:
    """A scenario of ``fmu`` through ``interface`` (``extra``: more top-level keys, ``fmu_table``:
    more of ``[plant.fmu]``), named ``fmu-<stem>`` unless ``name`` is given."""
    name = name or f"fmu-{fmu.stem}"
    return f"""
name = "{name}"
duration = {duration}
sample_time = {dt}
{extra}

[plant]
model = "{fmu}"

[plant.fmu]
interface = "{interface}"
{fmu_table}
"""
