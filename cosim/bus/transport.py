"""The run's CAN bus: which python-can interface, on which channel, and how to open it.

``udp_multicast`` (the default) connects processes on one host with no kernel module and no
server. Each run gets its own multicast group and a free UDP port, so concurrent runs never hear
each other (sockets bound to one port see the datagrams of every group joined on the host: the
port is what separates runs). Traffic never leaves the host: the group is an IPv6
interface-local one (ff11::/16, which Linux loops back and never transmits) with hop limit 1;
where IPv6 is unavailable, an IPv4 group (239.255.0.0/16) with TTL 0, which Linux also keeps on
the host. (A TTL of 1 alone is not enough: such packets still reach the local network.)

Known behaviour of the transport, handled by the nodes and the runner: a sender receives its own
frames back (multicast loopback; they are recognized by their sender in the DBC), receive
timestamps replace the sender's (the log uses simulated time, never frame timestamps), and a
receiver whose socket buffer overflows during a burst loses frames (buffers are enlarged here,
lockstep keeps bursts to one tick, and losses are counted per sender).

``socketcan`` uses a (virtual) kernel CAN interface such as ``vcan0``; ``virtual`` is cosim's
in-process bus (``cosim.bus.inprocess``, the python-can interface ``cosim_virtual``), for in-process
runs, tests and campaigns.
"""

from __future__ import annotations

import errno
import ipaddress
import random
import socket
import struct
import sys
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import can

from cosim.bus.inprocess import InProcessBus
from cosim.bus.udp import ForeignDatagram, HostMulticastBus
from cosim.errors import CosimError

INTERFACES = ("udp_multicast", "socketcan", "virtual")
#: The python-can interface of a ``virtual`` run's bus: cosim's in-process bus, without copies.
VIRTUAL_INTERFACE = "cosim_virtual"
#: The python-can interface of a ``udp_multicast`` run's bus (``cosim.bus.udp``): it reads batches.
UDP_INTERFACE = "cosim_udp"
#: Frames one ``drain`` hands out at most before its caller gets control back.
DRAIN_LIMIT = 4096
_PORTS = (20000, 60000)


@dataclass(frozen=True)
class BusConfig:
    """Where a run's bus is: enough for any python-can program to join it."""

    interface: str
    channel: str
    port: int | None = None
    hop_limit: int | None = None
    fd: bool = False
    mirror: int | None = None
    """udp_multicast: the port (``port`` + 1) on which every frame also goes alone to the group, in
    python-can's own format (None: no mirror). Another port, not another group: python-can's
    ``udp_multicast`` binds the wildcard address, so it hears every group joined on its port."""

    def kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``can.Bus`` for this bus: a udp_multicast run's is ``cosim_udp``,
        which reads the datagrams that carry a participant's frames of a tick together."""
        kwargs: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.interface == "udp_multicast":
            kwargs |= {"interface": UDP_INTERFACE, "port": self.port, "hop_limit": self.hop_limit, "fd": True}
            if self.mirror:
                kwargs["mirror"] = self.mirror
        elif self.interface == "socketcan":
            kwargs["fd"] = self.fd
        elif self.interface == "virtual":
            kwargs["interface"] = VIRTUAL_INTERFACE
        return kwargs

    def describe(self) -> str:
        where = f"{self.interface} channel {self.channel}"
        return f"{where} port {self.port}" if self.port is not None else where

    def python_can(self) -> str:
        """The python-can call that joins this bus."""
        args = ", ".join(f"{key}={value!r}" for key, value in self.kwargs().items())
        return f"can.Bus({args})"

    def mirror_kwargs(self) -> dict[str, Any] | None:
        """Keyword arguments of ``can.Bus`` for python-can's ``udp_multicast`` on the mirror (None: none)."""
        if self.interface != "udp_multicast" or not self.mirror:
            return None
        return {"interface": "udp_multicast", "channel": self.channel, "port": self.mirror, "hop_limit": self.hop_limit}

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BusConfig:
        return cls(**data)


def allocate(
    interface: str,
    channel: str = "",
    port: int = 0,
    fd: bool = False,
    allow_network: bool = False,
    mirror: bool = False,
) -> BusConfig:
    """A bus for one run; empty ``channel`` and zero ``port`` pick fresh ones. A udp_multicast group
    whose scope reaches beyond this host is refused unless ``allow_network``, and so is a group and
    port that another co-simulation on this host is using; ``mirror``: the per-frame mirror on the
    next port, which must be free too."""
    if interface == "udp_multicast":
        config = _allocate_multicast(channel, port, fd, allow_network, mirror)
        if mirror:  # the next port: a tool finds it from the run's port alone
            assert config.port is not None
            config = BusConfig(config.interface, config.channel, config.port, config.hop_limit, fd, config.port + 1)
        _refuse_a_busy_bus(config)
        return config
    if interface == "socketcan":
        channel = channel or "vcan0"
        if not Path("/sys/class/net", channel).exists():
            raise CosimError(
                f"bus: there is no CAN interface {channel!r} on this machine; create a virtual one with "
                f"'sudo modprobe vcan && sudo ip link add dev {channel} type vcan && sudo ip link set up {channel}', "
                f'or use interface = "udp_multicast"'
            )
        return BusConfig("socketcan", channel, fd=fd)
    if interface == "virtual":
        return BusConfig("virtual", channel or f"cosim-{random.SystemRandom().getrandbits(48):012x}", fd=fd)
    raise CosimError(f"bus: unknown interface {interface!r}; use one of {', '.join(INTERFACES)}")


def group_scope(channel: str) -> str | None:
    """Why a multicast group's traffic can leave this host (None: it cannot), or an error for a
    channel that is no multicast group."""
    try:
        address = ipaddress.ip_address(channel)
    except ValueError:
        raise CosimError(
            f"bus: channel {channel!r} is not an IP address; a udp_multicast channel is a multicast group, "
            f"e.g. ff11::c05:1 (or leave it empty for a fresh one)"
        ) from None
    if not address.is_multicast:
        raise CosimError(f"bus: channel {channel} is not a multicast group (IPv6 ff00::/8, IPv4 224.0.0.0/4)")
    if address.version == 6:
        scope = int(address.packed[1]) & 0x0F
        if scope != 1:
            names = {2: "link-local", 4: "admin-local", 5: "site-local", 8: "organization-local", 14: "global"}
            return (
                f"its scope is {names.get(scope, f'scope {scope:x}')} (ff{address.packed[1]:02x}::/16), so its frames "
                f"go out on the network; an interface-local group (ff11::/16) stays on this host"
            )
    return None  # IPv4: sent with TTL 0, which keeps it on this host


def _allocate_multicast(channel: str, port: int, fd: bool, allow_network: bool, mirror: bool = False) -> BusConfig:
    rng = random.SystemRandom()
    port = port or _free_port(rng, 2 if mirror else 1)
    if channel:
        reason = group_scope(channel)
        if reason is not None and not allow_network:
            raise CosimError(
                f"bus: channel {channel}: {reason}; use it only with --allow-network "
                f"([bus] allow_network = true), or leave the channel empty for a host-local group"
            )
        ipv6 = ":" in channel
        hop_limit = (1 if ipv6 else 0) if reason is None else 1
        return BusConfig("udp_multicast", channel, port, hop_limit, fd)
    if _ipv6_multicast_works():
        return BusConfig("udp_multicast", f"ff11::c05:{rng.getrandbits(16):x}:{rng.getrandbits(16):x}", port, 1, fd)
    return BusConfig("udp_multicast", f"239.255.{rng.randrange(256)}.{rng.randrange(1, 255)}", port, 0, fd)


def _refuse_a_busy_bus(config: BusConfig) -> None:
    """Another co-simulation of this user registered on the same group and port: both would corrupt each other."""
    from cosim.bus import registry

    for info in registry.active():
        bus = info.get("bus", {})
        if bus.get("channel") == config.channel and bus.get("port") == config.port:
            raise CosimError(
                f"bus: {config.describe()} is in use by the running co-simulation {info.get('id')} "
                f"({info.get('scenario')}, pid {info.get('pid')}); give this run another port or channel, or leave "
                f"them empty for fresh ones"
            )


def _free_port(rng: random.Random, count: int = 1) -> int:
    """A UDP port (the first of ``count`` in a row) no socket on this host is bound to (a probe
    without SO_REUSEADDR would fail)."""
    for _ in range(200):
        port = rng.randrange(*_PORTS)
        if all(_port_is_free(p) for p in range(port, port + count)):
            return port
    raise CosimError("bus: found no free UDP port for the run's multicast bus")


def _port_is_free(port: int) -> bool:
    for family, address in ((socket.AF_INET6, "::"), (socket.AF_INET, "")):
        try:
            with socket.socket(family, socket.SOCK_DGRAM) as probe:
                probe.bind((address, port))
        except OSError as error:
            if error.errno == errno.EADDRINUSE:
                return False
            # the family is unavailable: the other one decides
    return True


def _ipv6_multicast_works() -> bool:
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as probe:
            group = socket.inet_pton(socket.AF_INET6, "ff11::c05:0:1")
            probe.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP, group + struct.pack("@I", 0))
        return True
    except OSError:
        return False


def open_bus(config: BusConfig, on_foreign: Callable[[ForeignDatagram], None] | None = None) -> can.BusABC:
    """Open the bus, with a clear error naming the bus if that fails. A udp_multicast bus is this
    host's own (``cosim.bus.udp.HostMulticastBus``): what arrives that is not a frame of the run goes
    to ``on_foreign``."""
    try:
        if config.interface == "udp_multicast":
            assert config.port is not None
            bus: can.BusABC = HostMulticastBus(
                config.channel, config.port, config.hop_limit or 0, fd=True, on_foreign=on_foreign, mirror=config.mirror
            )
        elif config.interface == "virtual":
            bus = InProcessBus(config.channel, share_frames=True)
        else:
            bus = can.Bus(**config.kwargs())
    except (can.CanError, OSError, ValueError) as error:
        raise CosimError(f"cannot open the bus {config.describe()}: {error}") from None
    return bus


def drain(bus: can.BusABC, timeout: float = 0.0, limit: int = DRAIN_LIMIT) -> Iterator[can.Message]:
    """The frames waiting on ``bus``: the first waited for up to ``timeout`` seconds, then every one
    already there, without waiting, but at most ``limit``: a bus that never falls silent (a flood, a
    chatty program) cannot keep a receive loop from its other duties (deadlines, Ctrl-C, the next
    tick). Every receive loop of cosim (runner, nodes, clients, monitor) takes its frames through here."""
    frame = bus.recv(timeout)
    count = 0
    while frame is not None:
        yield frame
        count += 1
        if count >= limit:
            return
        frame = bus.recv(0.0)


def silent(bus: can.BusABC) -> bool:
    """Whether nothing more can arrive on ``bus`` than it holds now: an in-process bus that no
    other bus shares any longer. A network bus can always hear from someone."""
    return bool(getattr(bus, "alone", False))


def drain_silent(bus: can.BusABC) -> Iterator[can.Message]:
    """Every frame a ``silent`` bus still holds, however many (no limit: nothing more can come)."""
    return drain(bus, limit=sys.maxsize)


def send_all(bus: can.BusABC, frames: list[can.Message]) -> None:
    """Send a participant's frames of a tick: in one datagram where the bus can (``send_batch``),
    else one by one."""
    batch = getattr(bus, "send_batch", None)
    if batch is not None:
        batch(frames)
    else:
        for frame in frames:
            bus.send(frame)
