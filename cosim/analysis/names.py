"""One naming of a run's signals for exports, plots and layouts, whatever the frame packing: ``<node>.<signal>``.

The bus packs a node's signals into as many frames as they need: an estimator of four states and
their diagnostics is ``EST_kalman_0`` and ``EST_kalman_1`` on classic CAN (eight bytes a frame) and
one ``EST_kalman`` on CAN FD, and the log has a decoded topic per message (``/can/EST_kalman_0``).
Wherever cosim names a signal for people and their scripts (table columns of ``cosim export``,
labels of ``cosim plot`` and of ``cosim layout``), it is named after the node that publishes it,
the same on both buses:

- an estimator's, a client's, the controller node's signals: ``<node>.<signal>``
  (``kalman.xhat_x1``, ``lsq.x1``, ``controller.reconfigured``);
- a sensor's reading and an actuator's command as sent: their one-signal messages
  (``SENSOR_x1.x1``, ``COMMAND_force.force``);
- the truth: ``state.<state>``, ``sensors.<sensor>``, ``inputs.commanded.<actuator>``,
  ``inputs.effective.<actuator>``, ``inputs.disturbance.<input>``, ``faults.noise.<sensor>``,
  ``faults.fault.<sensor>``, ``faults.measured.<sensor>``, ``faults.effectiveness.<actuator>``,
  ``faults.dropped``, ``faults.active``.

A node whose name is one of the truth prefixes (an estimator called ``state``) keeps its message
prefix (``EST_state.xhat_x1``). The map comes from the run's DBC (who sends each message, in which
role); a log without one keeps its topic names (``EST_kalman_0.xhat_x1``). Foxglove message paths
stay the log's topics (``/can/EST_kalman_0.xhat_x1``), which ``cosim layout`` resolves.
"""

from __future__ import annotations

from typing import Any

from cosim.bus.codec import CLIENT, CONTROL, ESTIMATE, MESSAGE_PREFIX, Codec
from cosim.bus.dbc import Role, load_dbc, message_roles
from cosim.errors import CodecError
from cosim.log.recorder import FAULTS, INPUTS, SENSORS, STATE, message_topic

#: The truth topics and the prefix of their names.
TRUTH_PREFIX = {STATE: "state", SENSORS: "sensors", INPUTS: "inputs", FAULTS: "faults"}
#: The roles whose messages are a node's signals, packed into as many frames as they need.
NODE_ROLES = (ESTIMATE, CLIENT, CONTROL)


def node_prefixes(codec: Codec) -> dict[str, str]:
    """Decoded topic of every node message (estimates, clients, controller status) → its node's name."""
    return _node_prefixes({spec.name: (spec.role, spec.sender) for spec in codec.specs.values()})


def _node_prefixes(roles: dict[str, tuple[Role, str]]) -> dict[str, str]:
    """``node_prefixes`` of the messages' roles and senders, by name."""
    reserved = set(TRUTH_PREFIX.values())
    found = {}
    for name, (role, sender) in roles.items():
        if role in NODE_ROLES:
            found[message_topic(name)] = sender if sender not in reserved else f"{MESSAGE_PREFIX[role]}_{sender}"
    return found


def prefixes(dbc: str | bytes | None) -> dict[str, str]:
    """Topic → the prefix of its fields' names, for a log with the DBC ``dbc`` (None: no renaming):
    the truth topics and the node messages; other topics (``/can/SENSOR_x1``) are named by their
    last path component."""
    found = dict(TRUTH_PREFIX)
    if dbc:
        # Read by cantools, not compiled into a codec: any DBC cantools reads names its messages
        # (one cosim's codec cannot compile too: big-endian or multiplexed signals, extended ids).
        try:
            database = load_dbc(dbc.decode(errors="replace") if isinstance(dbc, bytes) else dbc, strict=False)
        except CodecError:
            return found  # not a CAN database: topics keep their names
        found.update(_node_prefixes(message_roles(database)))
    return found


def prefix(topic: str, known: dict[str, str]) -> str:
    """The name prefix of a topic's fields."""
    return known.get(topic) or topic.rsplit("/", 1)[-1]


def signal_name(topic: str, field: str, known: dict[str, str]) -> str:
    """The stable name of one field of a topic: ``kalman.xhat_x1`` for ``/can/EST_kalman_0``, ``xhat_x1``."""
    return f"{prefix(topic, known)}.{field}"


def units(schemas: dict[str, dict[str, Any]]) -> dict[str, str]:
    """The unit of every state, sensor and actuator of a log, from the JSON Schemas of its truth
    topics (``cosim.log.writer.number`` writes "<name> [<unit>]"); names without a unit are left out."""
    found: dict[str, str] = {}
    for topic, nested in ((STATE, None), (SENSORS, None), (INPUTS, "commanded")):
        properties = schemas.get(topic, {}).get("properties", {})
        if nested is not None:
            properties = properties.get(nested, {}).get("properties", {})
        for name, schema in properties.items():
            description = schema.get("description", "") if isinstance(schema, dict) else ""
            if description.endswith("]") and "[" in description and description[description.rindex("[") + 1 : -1]:
                found[name] = description[description.rindex("[") + 1 : -1]
    return found
