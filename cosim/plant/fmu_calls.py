"""Every FMI call of an FMU instance, watched: what the FMU logs, which call is under way, and a
failed call as one line.

FMPy sends each FMI function of an instance through one method (``_call(name, *args)``), which
raises ``FMICallException`` for a status above Warning. ``CallWatch.watch`` wraps that method:

- before each call, its name goes into ``slot`` (a small shared memory the process that runs the
  FMU's host reads when the FMU does not answer or crashes), and a NUL byte after it returns;
- a failed call becomes ``FmuCallError``: the FMU, the call, its status, the time and the FMU's last
  log message, in one line. The first failure is kept (``failure``) because FMPy's solver calls the
  FMU from C callbacks, where an exception is printed and lost;
- the FMU's logger callback (FMI 2 ``logger``, FMI 3 ``logMessage``) collects its messages
  (``FmuMessage``) in ``messages`` (or hands each to ``on_message``), instead of FMPy's default, which
  prints them.

FMI 2's logger is variadic: FMPy formats its message through a proxy in C (``addLoggerProxy``)
which keeps the Python logger it wraps in one pointer for the whole process. A logger per instance
would leave that pointer to a freed callback once its instance is gone, and the next message of
another instance would crash the process. So FMI 2 instances all get one callback structure that
lives as long as the process (``fmi2_callbacks``), whose logger hands a message to the watch of
the call under way (``_current``: calls are made one at a time).
"""

from __future__ import annotations

import mmap
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cosim.errors import ModelError

#: The FMI status names, by value (fmi2Status, fmi3Status).
STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
#: The bytes of the slot that name the call under way.
SLOT_SIZE = 64
#: A tick's request to an FMU's host process and its answer (``cosim.plant.fmu_host``): a tag byte,
#: the request's header (the plant's key, the number of actuators), then float64 values.
STEP, ANSWER = b"s", b"o"
STEP_HEADER = struct.Struct("<ii")


@dataclass(frozen=True)
class FmuMessage:
    """One message of the FMU: logged through its logger callback (``source`` "logger", with its
    FMI ``status`` and ``category``) or printed by its code on ``stdout``/``stderr`` (one line)."""

    source: str
    status: str
    category: str
    text: str

    def __str__(self) -> str:
        if self.source == "logger":
            category = f" {self.category}" if self.category else ""
            return f"[{self.status}]{category}: {self.text}"
        return f"({self.source}) {self.text}"


class FmuCallError(ModelError):
    """An FMI call of the plant's FMU that failed (or a solver failure on it), in one line."""


class CallWatch:
    """Watches the FMI calls of the instances of one FMU (``name``: its file's name)."""

    def __init__(self, name: str, version: int, slot: mmap.mmap | None = None) -> None:
        self.name, self.version, self.slot = name, version, slot
        self.time = 0.0
        """The simulated time the calls are made at (for the error's line)."""
        self.messages: list[FmuMessage] = []
        """What it logged or printed, until taken (``take``)."""
        self.last_logged: FmuMessage | None = None
        self.failure: FmuCallError | None = None
        self.fatal = False
        """A call returned Fatal: no further call to any instance is allowed (FMI 2.0 §2.1.3)."""
        self.on_message: Callable[[FmuMessage], None] | None = None

    def watch(self, fmu: Any) -> Any:
        """``fmu`` (an FMPy instance) with its calls watched."""
        from fmpy.fmi1 import FMICallException

        call = fmu._call
        slot = self.slot

        def watched(fname: str, *args: Any) -> Any:
            global _current
            _current = self
            if slot is not None:
                slot[: len(fname) + 1] = fname.encode() + b"\0"
            if fname.endswith("SetTime"):  # the solver's time, for the line of a call that fails inside it
                self.time = float(args[1])
            try:
                result = call(fname, *args)
            except FMICallException as error:
                raise self.failed(fname, STATUS[error.status] if 0 <= error.status < 6 else str(error.status)) from None
            if slot is not None:
                slot[0] = 0
            return result

        fmu._call = watched
        return fmu

    def failed(self, call: str, status: str) -> FmuCallError:
        """The error of ``call`` returning ``status`` (kept as the first failure)."""
        self.fatal = self.fatal or status == "Fatal"
        error = FmuCallError(f"{self.name}: {call} returned {status} at t = {self.time:g} s; {self.last_words()}")
        self.failure = self.failure or error
        return error

    def solver_failed(self, what: str) -> FmuCallError:
        """The error of FMPy's model-exchange solver (CVode) on this FMU (``what``: FMPy's message)."""
        cvode = re.match(r"CVode error \(code (\S+)\).*?: (.*)$", what, re.S)
        if cvode is not None:
            what = f"CVode's error {cvode[1]}: {cvode[2].strip()}"
        error = self.failure or FmuCallError(
            f"{self.name}: the model-exchange solver (CVode) failed at t = {self.time:g} s: {what}; {self.last_words()}"
        )
        self.failure = error
        return error

    def last_words(self) -> str:
        return f"its last message: {self.last_logged}" if self.last_logged else "it logged no message"

    def take(self) -> list[FmuMessage]:
        """The messages since the last take."""
        taken, self.messages = self.messages, []
        return taken

    def check(self) -> None:
        """Raise the first failure (of a call made from a C callback, where it was lost)."""
        if self.failure is not None:
            raise self.failure

    def logger(self) -> Callable[..., None]:
        """The FMU's logMessage callback for FMPy's ``instantiate_fmu`` (FMI 3: one per instance,
        kept by FMPy's instance object)."""

        def logger3(environment: Any, status: int, category: Any, message: Any) -> None:
            self._logged(status, category, message)

        return logger3

    def instantiating(self) -> None:
        """The calls about to be made (an instantiation) are this watch's."""
        global _current
        _current = self

    def _logged(self, status: int, category: Any, message: Any) -> None:
        message = FmuMessage(
            "logger", STATUS[status] if 0 <= status < 6 else str(status), _text(category), _text(message).rstrip()
        )
        self.last_logged = message
        if self.on_message is not None:
            self.on_message(message)
        else:
            self.messages.append(message)


def _text(value: Any) -> str:
    if value is None:
        return ""
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


class Said:
    """How many messages an FMU logged (by status) and lines it printed: the run's summary line."""

    def __init__(self) -> None:
        self.logged: dict[str, int] = {}
        self.printed = 0

    def add(self, messages: list[FmuMessage]) -> None:
        for m in messages:
            if m.source == "logger":
                self.logged[m.status] = self.logged.get(m.status, 0) + 1
            else:
                self.printed += 1

    def __bool__(self) -> bool:
        return bool(self.logged or self.printed)

    def __str__(self) -> str:
        parts = []
        if self.logged:
            count = sum(self.logged.values())
            by_status = ", ".join(f"{n} {status}" for status, n in self.logged.items())
            parts.append(f"logged {count} message{'s' if count != 1 else ''} ({by_status})")
        if self.printed:
            parts.append(f"printed {self.printed} line{'s' if self.printed != 1 else ''}")
        return " and ".join(parts)


_current: CallWatch | None = None
"""The watch of the FMI call under way (FMI 2's logger hands it the message)."""
_FMI2_CALLBACKS: Any = None
_FMI2_LOGGER: Any = None
"""Our logger (kept alive: the callbacks hold only its address)."""


def _logger2(component: Any, instance: Any, status: int, category: Any, message: Any) -> None:
    if _current is not None:
        _current._logged(status, category, message)


def fmi2_callbacks() -> Any:
    """The FMI 2 callback functions of every instance of this process (see the module's docstring).

    FMPy's native logger proxy (``addLoggerProxy``) forwards to one logger for the whole process, the
    one registered last: FMPy's own ``simulate_fmu`` in the same process registers its own, after
    which an instance of ours would log to it. So ours is registered again for each instance."""
    global _FMI2_CALLBACKS, _FMI2_LOGGER
    from ctypes import byref

    from fmpy.logging import addLoggerProxy

    if _FMI2_CALLBACKS is None:
        from fmpy import calloc, free
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )

        callbacks = fmi2CallbackFunctions()
        _FMI2_LOGGER = fmi2CallbackLoggerTYPE(_logger2)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        _FMI2_CALLBACKS = callbacks
    _FMI2_CALLBACKS.logger = _FMI2_LOGGER  # the proxy's target is ours again, then the proxy is the logger
    addLoggerProxy(byref(_FMI2_CALLBACKS))
    return _FMI2_CALLBACKS
