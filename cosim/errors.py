"""User-facing errors: each carries one message that names what is wrong and how to fix it.

The CLI prints these without a traceback; anything else escaping is a bug.
"""


class CosimError(Exception):
    """Base class of errors caused by the user's input rather than by a bug."""


class ScenarioError(CosimError):
    """A scenario file is malformed or asks for something impossible."""


class ModelError(CosimError):
    """A plant model (MJCF file or plant module) is inconsistent."""


class CodecError(CosimError):
    """A value cannot be encoded into its CAN signal, or a frame cannot be decoded."""


class LogError(CosimError):
    """An MCAP log cannot be read."""
