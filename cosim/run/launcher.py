"""The participants a runner waits for: estimator and controller processes, in-process nodes,
external clients.

Each knows how to tell the runner what went wrong with it (a process that exited, with its exit
status and last output; one that hangs; a client that went away) and how to stop.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from cosim.blas import ONE_THREAD_ENV
from cosim.bus.registry import alive
from cosim.bus.transport import open_bus
from cosim.run.node import ESTIMATOR_FAILED, ControllerNode, EstimatorFailure, EstimatorNode, NodeSpec
from estimators import Estimator
from estimators.controller import Controller


class Participant:
    """A node the runner expects heartbeats from."""

    name: str
    lockstep: bool = True
    kind = "participant"

    def service(self) -> None:
        """Let an in-process participant handle what is waiting for it (others run on their own)."""

    def failure(self) -> str | None:
        """Why the participant can no longer answer, if it is known to have failed."""
        return None

    @property
    def estimator_failed(self) -> bool:
        """Its failure is its estimator's (the step raised): the run goes on without it."""
        return False

    def hung(self, tick: int, waited: float) -> str:
        """The report for a participant that has not answered tick ``tick`` in ``waited`` seconds."""
        return f"{self.kind} {self.name} did not answer tick {tick} within {waited:g} s"

    def stop(self, timeout: float) -> str | None:
        """Stop (after the runner's NMT stop); returns a warning if that did not go cleanly."""
        return None


class ProcessNode(Participant):
    """An estimator or controller node in a process of its own (``cosim node NAME --spec FILE``)."""

    def __init__(self, spec: NodeSpec, workdir: Path, kind: str = "node") -> None:
        self.name = spec.name
        self.kind = kind
        spec_path = workdir / f"{spec.name}.json"
        # Private to the user (the run's folder is too): with SecOC the spec holds the node's keys,
        # and the node deletes it once read.
        with os.fdopen(os.open(spec_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "w") as file:
            file.write(spec.to_json())
        self.output = workdir / f"{spec.name}.log"
        with open(self.output, "wb") as output:
            # A session of its own: Ctrl-C in the terminal reaches the runner only, which stops the
            # nodes itself after finishing the log.
            self.process = subprocess.Popen(
                [sys.executable, "-m", "cosim.cli", "node", spec.name, "--spec", str(spec_path)],
                stdin=subprocess.DEVNULL,
                stdout=output,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                env={**os.environ, **ONE_THREAD_ENV},
            )

    def last_output(self, lines: int = 12) -> str:
        try:
            text = self.output.read_text(errors="replace").rstrip()
        except OSError:
            return "(no output)"
        tail = text.splitlines()[-lines:]
        return "\n".join("    " + line for line in tail) if tail else "    (no output)"

    def failure(self) -> str | None:
        code = self.process.poll()
        if code is None:
            return None
        if code == ESTIMATOR_FAILED:
            return f"node {self.name}: its estimator raised; its traceback:\n{self.last_output(lines=40)}"
        return f"node {self.name} exited with status {code}; its last output:\n{self.last_output()}"

    @property
    def estimator_failed(self) -> bool:
        return self.process.poll() == ESTIMATOR_FAILED

    def hung(self, tick: int, waited: float) -> str:
        self.process.kill()
        self.process.wait()
        return (
            f"node {self.name} did not answer tick {tick} within {waited:g} s and was killed (it hung; raise "
            f"[timing] node_timeout if it is only slow); its last output:\n{self.last_output()}"
        )

    def stop(self, timeout: float) -> str | None:
        try:
            code = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.terminate()
            try:
                self.process.wait(2.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
            return f"node {self.name} did not exit after the stop command and was terminated"
        if code != 0:
            return f"node {self.name} exited with status {code}; its last output:\n{self.last_output()}"
        return None


class LocalNode(Participant):
    """An estimator node driven by the runner in its own process (the ``virtual`` interface)."""

    kind = "node"
    node: EstimatorNode | ControllerNode  # a LocalController's is its ControllerNode

    def __init__(self, spec: NodeSpec, estimator: Estimator) -> None:
        self.name = spec.name
        self.bus = open_bus(spec.bus)
        self.node = EstimatorNode(spec, self.bus, estimator)
        self.node.client.join()
        self._failure: str | None = None

    def service(self) -> None:
        if self._failure is not None:
            return
        try:
            self.node.service()
        except EstimatorFailure as failure:  # its estimator's code raised: as its process would exit
            self._failure = str(failure)

    def failure(self) -> str | None:
        return self._failure

    @property
    def estimator_failed(self) -> bool:
        return self._failure is not None

    def stop(self, timeout: float) -> str | None:
        if self._failure is None:
            self.node.service()  # take the stop command
        self.bus.shutdown()
        return None


class LocalController(LocalNode):
    """The controller node driven by the runner in its own process (the ``virtual`` interface)."""

    kind = "controller"

    def __init__(self, spec: NodeSpec, controller: Controller) -> None:
        self.name = spec.name
        self.bus = open_bus(spec.bus)
        self.node = ControllerNode(spec, self.bus, controller)
        self.node.client.join()
        self._failure = None


class ExternalClient(Participant):
    """A client declared in the scenario, or an estimator node marked external: started by the user."""

    def __init__(self, name: str, lockstep: bool, kind: str = "client") -> None:
        self.name = name
        self.lockstep = lockstep
        self.kind = kind

    def hung(self, tick: int, waited: float) -> str:
        return f"{self.kind} {self.name} did not answer tick {tick} within {waited:g} s: has it stopped?"


def remove_stale_workdirs() -> None:
    """Remove the node folders (specs and outputs) of runs whose runner was killed before it could."""
    for folder in Path(tempfile.gettempdir()).glob("cosim-nodes-*-*"):
        try:
            pid = int(folder.name.split("-")[2])
            if folder.lstat().st_uid != os.getuid() or alive(pid):
                continue
            shutil.rmtree(folder, ignore_errors=True)
        except (ValueError, IndexError, OSError):
            continue
