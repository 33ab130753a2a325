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


class Interruption(KeyboardInterrupt):
    """A run stopped by a signal (Ctrl-C: SIGINT, or SIGTERM): ``signum`` says which (the CLI exits
    with 128 + signum), ``detail`` what was under way when it came, if that is worth a line."""

    def __init__(self, signum: int, detail: str = "") -> None:
        import signal

        super().__init__(detail or signal.Signals(signum).name)
        self.signum, self.detail = signum, detail
