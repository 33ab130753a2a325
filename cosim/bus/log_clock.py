"""The clocks of other tools' CAN logs: what their times count from, in which zone, and how a date
of one is said.

A CAN log's times are one of:

- ``UTC``: seconds since the Unix epoch (candump's kernel clock, python-can's CSV and SQLite logs,
  an MF4 file's header, which records UTC);
- ``LOCAL``: the wall clock of the PC that recorded it, with no zone (the ``date`` of Vector's
  ASC, the header of its BLF, PEAK's TRC ``$STARTTIME``). Such a log is logged with its digits
  kept as if they were UTC and its zone ``UNKNOWN``, or, given the zone it was recorded in
  (``cosim import --timezone Europe/Berlin``), converted to UTC and that zone named;
- ``NO_DATE``: no date at all (a TRC 1.0 trace, an ASC without its ``date`` line): times from the
  recording's start, logged from the epoch.

An imported log names its zone in ``cosim.import`` ``time_zone``: ``UTC``, an IANA zone,
``UNKNOWN`` or ``NO_DATE``; ``date_text`` says a time of it that way. Times in the logs' text are
read as decimals (``nanoseconds``), never through a float: a candump's 0.000200 s stays 200 µs.
"""

from __future__ import annotations

from datetime import UTC as _UTC
from datetime import datetime, timedelta, tzinfo
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from cosim.errors import CosimError

UTC = "UTC"
LOCAL = "local"
UNKNOWN = "unknown"
NO_DATE = "none"

#: The clock of each format's times (by ``cosim.bus.canlogs.FORMATS``' names); a text log of a
#: local clock may turn out to have no date.
CLOCKS = {
    "candump": UTC,
    "blf": LOCAL,
    "asc": LOCAL,
    "trc": LOCAL,
    "mf4": UTC,
    "python-can csv": UTC,
    "python-can sqlite": UTC,
}

_EPOCH = datetime(1970, 1, 1)
_NS = 1_000_000_000


def nanoseconds(text: str, scale: int = 9) -> int:
    """The integer number of ns a decimal text of units of 10^-``scale`` s says (9: seconds, 6:
    milliseconds), exactly; a ValueError for text that is not a decimal number."""
    try:
        value = Decimal(text).scaleb(scale)
    except InvalidOperation:
        raise ValueError(f"{text!r} is not a time") from None
    if not value.is_finite():
        raise ValueError(f"{text!r} is not a time")
    return int(value.to_integral_value(ROUND_HALF_EVEN))


def wall_clock_ns(when: datetime) -> int:
    """A naive date and time as ns since the epoch, counted as if it were UTC (its digits kept)."""
    delta = when - _EPOCH
    return (delta.days * 86_400 + delta.seconds) * _NS + delta.microseconds * 1000


def time_zone(name: str) -> tzinfo:
    """``--timezone``: UTC or an IANA zone (Europe/Berlin); one line naming the form otherwise."""
    if name.upper() == UTC:
        return _UTC
    try:
        return ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError):
        raise CosimError(
            f"--timezone {name}: not a time zone; give an IANA name (Europe/Berlin, America/Detroit) or UTC"
        ) from None


def zone_name(zone: tzinfo) -> str:
    """The name an imported log records a zone under (``time_zone``)."""
    return zone.key if isinstance(zone, ZoneInfo) else UTC


def local_to_utc_ns(local_ns: int, zone: tzinfo) -> int:
    """The UTC time of a wall-clock time (``wall_clock_ns``) in ``zone``; an hour repeated when the
    clocks go back is taken at its first pass."""
    offset = zone.utcoffset(_EPOCH + timedelta(seconds=local_ns // _NS)) or timedelta(0)
    return local_ns - round(offset.total_seconds()) * _NS


def date_text(time_ns: int, zone: str) -> str | None:
    """A time of an imported log as a date to the millisecond, saying its zone as ``time_zone``
    records it (``2025-02-17 16:41:23.658 local time, zone unknown``); None for a log with no date."""
    if zone == NO_DATE:
        return None
    seconds, rest = divmod(time_ns, _NS)
    stamp = datetime.fromtimestamp(seconds, _UTC) + timedelta(microseconds=rest // 1000)
    if zone not in (UTC, UNKNOWN):
        try:
            stamp = stamp.astimezone(ZoneInfo(zone))
        except (ZoneInfoNotFoundError, ValueError):
            zone = UTC  # a zone this machine does not know: said in UTC
    text = stamp.replace(tzinfo=None).isoformat(sep=" ", timespec="milliseconds")
    if zone == UTC:
        return f"{text} UTC"
    if zone == UNKNOWN:
        return f"{text} local time, zone unknown"
    return f"{text} {stamp.tzname()} ({zone})"


def times_caveat(zone: str) -> str | None:
    """What an imported log's times are where they are not in a known zone, in one line for the
    places that show them as dates (None: UTC or a named zone)."""
    if zone == UNKNOWN:
        return (
            "the log's times are the local time of its recording, zone unknown, taken as if they were UTC "
            "(cosim import --timezone ZONE gives UTC)"
        )
    if zone == NO_DATE:
        return "the log records no date: its times count from its start, as if from the Unix epoch"
    return None
