"""Co-simulation testbed for fault-tolerant state estimation: runner, bus, codec, logging, CLI."""

__version__ = "0.1.0"
