"""MJCF plant models, each paired with a small module that names its signals and parameters."""

from __future__ import annotations

from mjcf import masses, three_tank, vessel
from mjcf._plant import Channel, Parameter, PlantInfo

PLANTS: dict[str, PlantInfo] = {info.name: info for info in (masses.INFO, three_tank.INFO, vessel.INFO)}


def get(name: str) -> PlantInfo:
    """The plant registered under ``name``; a KeyError lists the known ones."""
    try:
        return PLANTS[name]
    except KeyError:
        raise KeyError(f"unknown plant {name!r}; known plants: {', '.join(sorted(PLANTS))}") from None


__all__ = ["PLANTS", "Channel", "Parameter", "PlantInfo", "get"]
