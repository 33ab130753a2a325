"""A batch's estimators (``cosim.campaign.batch``): each estimator's K instances, where their
inputs come from and where their values go, and the batched steps that step them: one per
estimator, or one for several estimators of a kind whose batched step takes each instance's own
design (``Estimator.joint_batch_key``: E × K instances, estimator after estimator)."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np

from cosim.bus.codec import estimated_state
from cosim.run.plan import RunPlan
from estimators.batched import BatchEstimate, BatchStep, batch_of


class Estimators:
    """One estimator of the scenario over the batch's runs: its K instances (stepped by a
    ``Stepped``), where their inputs come from and where their values go (its node's signals)."""

    def __init__(self, name: str, plans: Sequence[RunPlan], sensors: tuple[str, ...], actuators: tuple[str, ...]):
        self.name = name
        self.instances = [copy.deepcopy(plan.estimators[name]) for plan in plans]  # the plan's, never stepped
        model = self.instances[0].model
        self.outputs = [sensors.index(n) if n in sensors else -1 for n in model.outputs]
        self.inputs = [actuators.index(n) if n in actuators else -1 for n in model.inputs]
        codec = plans[0].codec
        self.messages = codec.data_messages(name)
        self.signals = [signal for message in self.messages for signal in message.signals]
        self.states = {s: model.states.index(state) for s in self.signals if (state := estimated_state(s)) is not None}
        self.diagnostics = [s for s in self.signals if s not in self.states]
        channels = [channel for message in self.messages for channel in message.channels]
        self.lower = np.array([c.minimum for c in channels])
        self.upper = np.array([c.maximum for c in channels])
        self.as_carried = codec.carried_of(self.messages)
        self.u = np.zeros((len(plans), model.m))  # a command that never came is 0 (as its node holds it)
        self.failed: dict[int, str] = {}

    def given(self, y: np.ndarray, u_cmd: np.ndarray, commanded: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Its y (K, p) and u (K, m) of tick k, from the tick's readings (K, sensors; NaN where not
        sent) and commands (K, actuators; those ``commanded`` arrived, by actuator or (K, actuators)
        by run, the others its node holds)."""
        if commanded.ndim == 1:
            given = [i for i in self.inputs if i >= 0 and commanded[i]]
            self.u[:, [j for j, i in enumerate(self.inputs) if i >= 0 and commanded[i]]] = u_cmd[:, given]
        else:
            for j, i in enumerate(self.inputs):
                if i >= 0:
                    self.u[:, j] = np.where(commanded[:, i], u_cmd[:, i], self.u[:, j])
        ys = np.stack([y[:, i] if i >= 0 else np.full(len(y), np.nan) for i in self.outputs], axis=1)
        return ys, self.u.copy()

    def carried(self, estimate: BatchEstimate) -> np.ndarray:
        """The values its frames carry of its ``estimate``, (K, signals), in ``signals`` order."""
        self.failed = estimate.failed
        columns = [estimate.x[:, self.states[s]] if s in self.states else estimate.diagnostics[s] for s in self.signals]
        self.raw = np.stack(columns, axis=1).astype(float) if columns else np.zeros((len(estimate.x), 0))
        # sent at the bound it crossed (the node saturates), and as the frame carries it
        return self.as_carried(np.minimum(np.maximum(self.raw, self.lower), self.upper))


class Stepped:
    """Estimators of a batch stepped by one batched step: one estimator's K instances, or those of
    several estimators whose kind steps their designs together (``Estimator.joint_batch_key``), as
    E × K instances, estimator after estimator."""

    def __init__(self, members: Sequence[Estimators]) -> None:
        self.members = list(members)
        self.batch: BatchStep = batch_of([instance for member in members for instance in member.instances])

    def step(self, inputs: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> list[np.ndarray]:
        """Each member's values of tick k (``Estimators.carried``), in order, from its ``inputs``:
        its readings, commands and which came (``Estimators.given``)."""
        given = [member.given(*each) for member, each in zip(self.members, inputs, strict=True)]
        if len(given) == 1:
            return [self.members[0].carried(self.batch.step(*given[0]))]
        estimate = self.batch.step(np.concatenate([ys for ys, _ in given]), np.concatenate([u for _, u in given]))
        runs = len(given[0][0])
        return [member.carried(_rows(estimate, j * runs, runs)) for j, member in enumerate(self.members)]

    @staticmethod
    def of(estimators: Sequence[Estimators]) -> list[Stepped]:
        """The batch's estimators by step: those of a kind whose joint keys agree together, each
        other one by itself, in the order of their first member."""
        groups: dict[Any, list[Estimators]] = {}
        for e in estimators:
            key = e.instances[0].joint_batch_key()
            groups.setdefault(e.name if key is None else (type(e.instances[0]), key), []).append(e)
        return [Stepped(members) for members in groups.values()]


def _rows(estimate: BatchEstimate, start: int, count: int) -> BatchEstimate:
    """Rows [start, start + count) of a batched ``estimate``, renumbered from 0."""
    stop = start + count
    return BatchEstimate(
        estimate.x[start:stop],
        {name: values[start:stop] for name, values in estimate.diagnostics.items()},
        {row - start: why for row, why in estimate.failed.items() if start <= row < stop},
    )
