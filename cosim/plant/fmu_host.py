"""The process an FMU plant runs in: ``python -m cosim.plant.fmu_host FD SLOT_FD PARENT_PID``.

The runner's side (``cosim.plant.fmu_process``) starts it and sends it requests over the
connection on file descriptor FD; it runs them on ``FmuPlant`` instances (one per plant the runner
opens) and answers each. Why a process of its own, and what it costs: docs/fmi.md, "How the FMU is
isolated".

- Requests: pickled ``(op, key, args)``, op one of ``open`` (an FmuPlant from the FMU's path, its
  ``[plant.fmu]`` settings and the plant's arguments), ``reset``, ``set_state``, ``linearize``,
  ``close``; ``key`` names the plant. A tick's step is raw bytes: ``STEP``, the key and the number
  of actuators (``STEP_HEADER``), then the actuators' and the disturbance inputs' float64 values.
- Answers: pickled ``("ok", value)``, ``("error", line)`` (a ModelError, e.g. a failed FMI call)
  or ``("bug", line, traceback)``; a step's, ``ANSWER`` then the new states' and sensors' float64
  values. Before an answer, ``("log", FmuMessage)`` for each message the FMU logs, sent as it logs
  it (so that a crash loses none).
- What the FMU's code (or FMPy) prints goes to this process's standard output and error, pipes the
  runner reads: C's buffers are flushed before each answer.
- The call under way is named in the shared slot (SLOT_FD, ``fmu_calls.SLOT_SIZE`` bytes).

It dies with the runner (``PR_SET_PDEATHSIG``) and ignores SIGINT: Ctrl-C reaches the whole
process group, and it is the runner that decides what a stop does to the FMU.
"""

from __future__ import annotations

import ctypes
import mmap
import os
import pickle
import signal
import sys
import traceback
from multiprocessing.connection import Connection
from types import SimpleNamespace
from typing import Any

import numpy as np

from cosim.errors import ModelError
from cosim.plant import fmu_model
from cosim.plant.fmu import FmuPlant
from cosim.plant.fmu_calls import ANSWER, SLOT_SIZE, STEP, STEP_HEADER, FmuCallError, FmuMessage

_PR_SET_PDEATHSIG = 1


class Host:
    """The plants of one host process, by key."""

    def __init__(self, connection: Connection, slot: mmap.mmap) -> None:
        self.connection, self.slot = connection, slot
        self.plants: dict[int, FmuPlant] = {}
        self._libc = ctypes.CDLL(None)

    def serve(self) -> None:
        while True:
            try:
                request = self.connection.recv_bytes()
            except EOFError:  # the runner closed its end
                return
            if request[:1] == STEP:  # a tick: raw float64s both ways, no pickling
                self._step(request)
                continue
            op, key, args = pickle.loads(request)
            try:
                answer: tuple[Any, ...] = ("ok", getattr(self, op)(key, *args))
            except ModelError as error:
                answer = ("error", str(error))
            except Exception as error:  # noqa: BLE001 (a bug: its traceback goes back to the runner)
                answer = ("bug", f"{type(error).__name__}: {error}", traceback.format_exc())
            self._flush()
            self.connection.send_bytes(pickle.dumps(answer))

    def _step(self, request: bytes) -> None:
        key, m = STEP_HEADER.unpack_from(request, 1)
        values = np.frombuffer(request, dtype=float, offset=1 + STEP_HEADER.size)
        try:
            plant = self.plants[key]
            plant.step(values[:m], values[m:])
            answer = ANSWER + plant.reading().tobytes()
        except ModelError as error:
            answer = pickle.dumps(("error", str(error)))
        except Exception as error:  # noqa: BLE001 (a bug: its traceback goes back to the runner)
            answer = pickle.dumps(("bug", f"{type(error).__name__}: {error}", traceback.format_exc()))
        self._flush()
        self.connection.send_bytes(answer)

    def _flush(self) -> None:
        """What the FMU printed, out of C's and Python's buffers into the pipes, before the answer."""
        self._libc.fflush(None)
        sys.stdout.flush()
        sys.stderr.flush()

    def _log(self, message: FmuMessage) -> None:
        self.connection.send_bytes(pickle.dumps(("log", message)))

    def open(self, key: int, path: str, settings: dict[str, Any], arguments: dict[str, Any]) -> tuple[Any, ...]:
        model = fmu_model.read_fresh(path, SimpleNamespace(**settings))
        plant = FmuPlant(model, **arguments, slot=self.slot, on_message=self._log)
        self.plants[key] = plant
        return self._reading(plant)

    def reset(self, key: int, initial: dict[str, float] | None) -> tuple[Any, ...]:
        plant = self.plants[key]
        plant.reset(initial)
        return self._reading(plant)

    def set_state(self, key: int, x: np.ndarray) -> tuple[Any, ...]:
        plant = self.plants[key]
        plant.set_state(x)
        return self._reading(plant)

    def linearize(self, key: int, x: Any, u: Any, continuous: bool) -> tuple[Any, list[str], str]:
        plant = self.plants[key]
        model = plant.linearize(x, u, continuous=continuous)
        warnings, plant.warnings = plant.warnings, []
        return model, warnings, plant.operating_point

    def close(self, key: int) -> None:
        plant = self.plants.pop(key, None)
        if plant is not None:
            plant.close()

    @staticmethod
    def _reading(plant: FmuPlant) -> tuple[np.ndarray, np.ndarray]:
        return plant.state(), plant.sensors()


def _unraisable(hook: Any) -> Any:
    """Python's hook for what a C callback raised, without the FMU's failed calls: FMPy's solver
    calls the FMU from C, where an exception is printed and dropped; the call's watch keeps it and
    raises it after the solver's step (``CallWatch.check``)."""

    def unraisable(info: Any) -> None:
        if not isinstance(info.exc_value, FmuCallError):
            hook(info)

    return unraisable


def main(argv: list[str]) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.unraisablehook = _unraisable(sys.unraisablehook)
    prctl = getattr(ctypes.CDLL(None), "prctl", None)  # Linux's; elsewhere the host outlives a killed runner
    if prctl is not None:
        prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != int(argv[2]):  # the runner died before prctl: nobody to serve
        return
    connection = Connection(int(argv[0]))
    slot = mmap.mmap(int(argv[1]), SLOT_SIZE)
    Host(connection, slot).serve()


if __name__ == "__main__":
    main(sys.argv[1:])
