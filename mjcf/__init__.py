"""MJCF plant models, each paired with a small module that names its signals and parameters."""

from __future__ import annotations

from cosim.kinds import Kinds
from mjcf._plant import Channel, Parameter, PlantInfo


def _model_file(info: PlantInfo) -> list[str]:
    return [] if info.model_path.is_file() else [f"its model file {info.model_path} does not exist"]


#: The plants by name (``kinds``): built in, a module path to a ``PlantInfo``, or a plugin's entry point.
PLANTS: Kinds[PlantInfo] = Kinds(
    "plant",
    "cosim.plants",
    {"masses": "mjcf.masses:INFO", "three_tank": "mjcf.three_tank:INFO", "vessel": "mjcf.vessel:INFO"},
    PlantInfo,
    instance=True,
    key="name",
    check=_model_file,
)


def get(name: str) -> PlantInfo:
    """The plant called ``name``; a KeyError (``kinds.KindError``) in one line says why not."""
    return PLANTS[name]


__all__ = ["PLANTS", "Channel", "Parameter", "PlantInfo", "get"]
