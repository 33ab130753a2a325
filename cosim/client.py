"""Join a running co-simulation from your own program (see ``cosim.bus.client``, re-exported here)."""

from cosim.bus.client import Client, TickAssembler, TickFrames

__all__ = ["Client", "TickAssembler", "TickFrames"]
