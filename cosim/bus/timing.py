"""Lengths in bits of classic CAN and CAN FD data frames, with exact or worst-case bit stuffing.

A data frame's bits, in transmission order (ISO 11898-1:2015; docs/metrics.md has the tables):

- classic CAN, 11-bit id: SOF, ID(11), RTR, IDE, r0, DLC(4), data(8n), CRC(15); 29-bit id: SOF,
  ID-A(11), SRR, IDE, ID-B(18), RTR, r1, r0, DLC(4), data(8n), CRC(15). Stuffing covers SOF to the
  end of the CRC sequence: after five equal bits the transmitter inserts one of the opposite value,
  which itself counts as the first bit of the next run.
- CAN FD (ISO), 11-bit id: SOF, ID(11), RRS, IDE, FDF, res, BRS, ESI, DLC(4), data(8n); 29-bit id:
  SOF, ID-A(11), SRR, IDE, ID-B(18), RRS, FDF, res, BRS, ESI, DLC(4), data(8n). Dynamic stuffing
  covers SOF to the end of the data field; then the CRC field: stuff count (4 bits) and CRC (17 bits
  for n <= 16, 21 above) with a fixed stuff bit before the stuff count and after every 4 bits, 6
  or 7 fixed stuff bits, whatever the values.
- then, in both: CRC delimiter, ACK slot, ACK delimiter, EOF(7), and the 3-bit intermission (IFS)
  that must pass before the next frame: 13 bits, never stuffed.

With BRS set, the bits from ESI to the end of the CRC field go at the data bit rate (the switch
happens at the sample points of BRS and of the CRC delimiter; whole bits are counted on each side,
and a stuff bit in the phase of the bit it follows). Everything else goes at the nominal bit rate.

Exact stuffing needs the bits themselves, CRC included for classic CAN (its CRC sequence is
stuffed; the CAN FD CRC field is not dynamically stuffed, so its length does not depend on the
CRC's value). Stuff bits are counted by a finite automaton over bytes (state: the last bit and the
length of its run), so a frame costs a few table look-ups per byte.
"""

from __future__ import annotations

from functools import cache, lru_cache

import numpy as np

#: Bits after the CRC field: CRC delimiter, ACK slot, ACK delimiter, EOF (7), intermission (3).
TAIL_BITS = 13
_CRC15_POLY = 0x4599  # x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1

# Stuffing automaton: state 0 before SOF, else 1 + 5 b + (r - 1) after a run of r bits equal to b.


def _bit_step(state: int, bit: int) -> tuple[int, int]:
    """(stuff bits inserted, next state) after transmitting ``bit``."""
    if state == 0:
        return 0, 1 + 5 * bit
    last, run = divmod(state - 1, 5)
    run = run + 2 if bit == last else 1
    if run == 5:  # the stuff bit (1 - bit) starts a new run of one
        return 1, 1 + 5 * (1 - bit)
    return 0, 1 + 5 * bit + run - 1


def _chunk_table(width: int) -> list[list[tuple[int, int]]]:
    """table[state][chunk] = (stuff bits, next state) for every ``width``-bit chunk."""
    table = []
    for state in range(11):
        row = []
        for chunk in range(1 << width):
            stuffed, s = 0, state
            for i in range(width - 1, -1, -1):
                n, s = _bit_step(s, (chunk >> i) & 1)
                stuffed += n
            row.append((stuffed, s))
        table.append(row)
    return table


_CHUNKS = [_chunk_table(width) for width in range(9)]  # by width; 8: whole bytes


def stuff_bits(bits: int, length: int, state: int = 0) -> tuple[int, int]:
    """(stuff bits inserted, final state) when the ``length`` bits of ``bits`` (most significant
    first) are transmitted from automaton ``state`` (0: the first bit is SOF)."""
    head = length % 8
    stuffed, state = _CHUNKS[head][state][(bits >> (length - head)) & ((1 << head) - 1)]
    table = _CHUNKS[8]
    for shift in range(length - head - 8, -1, -8):
        n, state = table[state][(bits >> shift) & 0xFF]
        stuffed += n
    return stuffed, state


def _crc15_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = (crc << 1) ^ _CRC15_POLY if crc & 0x4000 else crc << 1
        table.append(crc & 0x7FFF)
    return table


_CRC15 = _crc15_table()


def crc15(bits: int, length: int) -> int:
    """The classic-CAN CRC sequence of ``length`` bits (SOF to the end of the data field): the
    remainder of their division by x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1, register
    starting at 0."""
    crc = 0
    head = length % 8
    for i in range(length - 1, length - 1 - head, -1):
        feedback = ((bits >> i) & 1) ^ (crc >> 14)
        crc = ((crc << 1) & 0x7FFF) ^ (_CRC15_POLY if feedback else 0)
    for shift in range(length - head - 8, -1, -8):
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15[((crc >> 7) ^ (bits >> shift)) & 0xFF]
    return crc


def _arbitration(can_id: int, extended: bool, fd: bool) -> tuple[int, int]:
    """(bits, length) from SOF to the bit before the control field's r0/FDF (SOF = 0)."""
    if extended:  # SOF, ID-A, SRR = 1, IDE = 1, ID-B, then RTR (classic) or RRS (FD) = 0
        bits = (((can_id >> 18) & 0x7FF) << 2 | 0b11) << 18 | (can_id & 0x3FFFF)
        return bits << 1, 1 + 11 + 2 + 18 + 1
    return (can_id & 0x7FF) << 2, 1 + 11 + 2  # SOF, ID, RTR/RRS = 0, IDE = 0


@lru_cache(maxsize=4096)  # bounded: a log of a flood of random ids must not grow it without end
def _classic_header(can_id: int, extended: bool, dlc: int) -> tuple[int, int, int, int]:
    """A classic frame's bits before its data (SOF to DLC: the arbitration field, r0 (and r1 for
    29-bit ids) = 0, the DLC): the CRC register and the stuffing automaton after them, (CRC, stuff
    bits, state, length)."""
    head, head_len = _arbitration(can_id, extended, False)
    control_len = 5 + (1 if extended else 0)
    bits, length = head << control_len | dlc, head_len + control_len
    stuffed, state = stuff_bits(bits, length)
    return crc15(bits, length), stuffed, state, length


def _fd_crc_field(length: int) -> int:
    """Bits of the ISO CAN FD CRC field: stuff count (4), CRC (17 or 21), fixed stuff bits."""
    crc = 17 if length <= 16 else 21
    return 4 + crc + (4 + crc + 3) // 4


@lru_cache(maxsize=4096)  # bounded, as ``_classic_header``
def _fd_header(can_id: int, extended: bool, brs: bool) -> tuple[int, int]:
    """An FD frame's bits before its ESI (SOF to BRS: the arbitration field, FDF = 1, res = 0, BRS):
    (their count with their stuff bits and the tail's, the stuffing automaton after them)."""
    head, head_len = _arbitration(can_id, extended, True)
    arbitration, arbitration_len = (head << 3) | (0b10 << 1) | int(brs), head_len + 3
    stuffed, state = stuff_bits(arbitration, arbitration_len)
    return arbitration_len + stuffed + TAIL_BITS, state


_ESI_DLC = _CHUNKS[5]  # ESI = 0 and the 4 DLC bits: the 5 bits before an FD frame's data


def _fd_before_data(can_id: int, extended: bool, brs: bool, dlc: int) -> tuple[int, int, int]:
    """An FD frame up to its data: (``_fd_header``'s bits, the stuff bits of ESI and the DLC, the
    automaton's state after them)."""
    nominal, state = _fd_header(can_id, extended, brs)
    stuffed, state = _ESI_DLC[state][dlc]
    return nominal, stuffed, state


# A frame is timed when planned, sent, logged and scored, all within its tick: a small cache holds
# those (as many hits at 256 entries as at 16 384 in a flooded run), and a fuzzed bus's 10 000 random
# frames do not fill the runner's memory with entries never asked for again (16 384 held 5 MB).
@lru_cache(maxsize=1024)
def frame_bits(can_id: int, extended: bool, fd: bool, brs: bool, dlc: int, data: bytes) -> tuple[int, int]:
    """(bits at the nominal bit rate, bits at the data bit rate) of one data frame, stuff bits
    counted exactly, intermission included. ``dlc`` is the data length code, ``data`` the payload
    (as many bytes as the DLC codes). The bits before the data depend only on the id, the flags and
    the DLC (cached); the data go byte by byte through the stuffing automaton (and the CRC)."""
    n = len(data)
    table = _CHUNKS[8]
    if not fd:  # the header's CRC register and stuffing state are the id's and DLC's: then byte by byte
        crc, stuffed, state, length = _classic_header(can_id, extended, dlc)
        for byte in data:
            crc = ((crc << 8) & 0x7FFF) ^ _CRC15[((crc >> 7) ^ byte) & 0xFF]
            more, state = table[state][byte]
            stuffed += more
        more, _ = stuff_bits(crc, 15, state)
        return length + 8 * n + 15 + stuffed + more + TAIL_BITS, 0
    # FD: ... FDF = 1, res = 0, BRS | ESI = 0, DLC, data; the CRC field is not dynamically stuffed
    nominal, stuffed, state = _fd_before_data(can_id, extended, brs, dlc)
    for byte in data:
        more, state = table[state][byte]
        stuffed += more
    fast = 5 + 8 * n + stuffed + _fd_crc_field(n)
    return (nominal, fast) if brs else (nominal + fast, 0)


def _as_arrays(table: list[list[tuple[int, int]]]) -> tuple[np.ndarray, np.ndarray]:
    """A chunk table as (stuff bits, next state) arrays indexed [state, chunk]."""
    pairs = np.array(table, dtype=np.int64)
    return pairs[..., 0], pairs[..., 1]


_STUFFED8, _NEXT8 = _as_arrays(_CHUNKS[8])
_STUFFED7, _NEXT7 = _as_arrays(_CHUNKS[7])  # a CRC sequence's first 7 bits
_CRC15_ARRAY = np.array(_CRC15, dtype=np.int64)


@cache
def _tables16() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stuffing automaton and the CRC-15 over 16 bits at once: for state s and word w (its first
    byte high), the stuff bits ``STUFF[s << 16 | w]`` and the next state ``NEXT[...]`` (times 2¹⁶,
    ready to index with), two 8-bit steps composed; and ``CRC[x]``, the register after 16 bits from
    zero, so that a register r takes the word w to ``CRC[(r << 1) ^ w]`` (the CRC is linear, and its
    15 bits meet the word's first 15). Built at the first use: 3.6 MB."""
    word = np.arange(1 << 16)
    high, low = word >> 8, word & 0xFF
    stuff = (_STUFFED8[:, high] + _STUFFED8[_NEXT8[:, high], low]).astype(np.int8).ravel()
    following = (_NEXT8[_NEXT8[:, high], low] << 16).astype(np.int32).ravel()
    crc = np.zeros(1 << 16, dtype=np.int64)
    for byte in (high, low):
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15_ARRAY[((crc >> 7) ^ byte) & 0xFF]
    return stuff, following, crc.astype(np.int32)


def frame_bits_rows(
    can_ids: list[int], extended: list[bool], dlcs: list[int], payloads: np.ndarray, fd: bool, brs: bool
) -> tuple[np.ndarray, np.ndarray]:
    """``frame_bits`` of C × R frames at once, equal to it frame by frame: frame (c, r) has id
    ``can_ids[c]`` (29-bit if ``extended[c]``), data length code ``dlcs[c]`` and the payload
    ``payloads[c, r]`` (C, R, n) uint8, all n bytes long, all CAN FD (with BRS or without) or all classic
    (C messages, each from R runs). The bits before the data are each column's (cached); the
    automaton and the CRC step through the payload two bytes at a time on arrays (``_tables16``; an
    odd last byte by the 8-bit tables): (nominal, data-rate) bits, each (C, R) int64."""
    data = np.asarray(payloads, dtype=np.int64)
    n, runs = data.shape[2], data.shape[1]
    if not fd:
        heads = np.array([_classic_header(*key) for key in zip(can_ids, extended, dlcs)], dtype=np.int64)
        crc, stuffed, state, length = (np.repeat(column[:, None], runs, axis=1) for column in heads.T)
    else:
        heads = np.array([_fd_before_data(i, x, brs, d) for i, x, d in zip(can_ids, extended, dlcs)], dtype=np.int64)
        nominal, stuffed, state = (np.repeat(column[:, None], runs, axis=1) for column in heads.T)
    if n >= 2:
        stuff16, next16, crc16 = _tables16()
        words = (data[:, :, 0 : n - 1 : 2] << 8) | data[:, :, 1:n:2]
        at = state << 16
        for j in range(n // 2):
            word = words[:, :, j]
            index = at + word
            stuffed = stuffed + stuff16.take(index)
            at = next16.take(index)
            if not fd:
                crc = crc16.take(((crc << 1) ^ word) & 0xFFFF)
        state = at >> 16
    if n % 2:
        byte = data[:, :, n - 1]
        if not fd:
            crc = ((crc << 8) & 0x7FFF) ^ _CRC15_ARRAY[((crc >> 7) ^ byte) & 0xFF]
        stuffed = stuffed + _STUFFED8[state, byte]
        state = _NEXT8[state, byte]
    if not fd:
        head = (crc >> 8) & 0x7F  # the CRC sequence's 15 bits: 7, then 8
        stuffed = stuffed + _STUFFED7[state, head]
        state = _NEXT7[state, head]
        stuffed = stuffed + _STUFFED8[state, crc & 0xFF]
        return length + (8 * n + 15 + TAIL_BITS) + stuffed, np.zeros_like(length)
    fast = (5 + 8 * n + _fd_crc_field(n)) + stuffed
    return (nominal, fast) if brs else (nominal + fast, np.zeros_like(nominal))


@cache
def frame_bits_worst_case(extended: bool, fd: bool, brs: bool, length: int) -> tuple[int, int]:
    """(nominal, data-rate) bits of a frame of ``length`` payload bytes with the most stuff bits
    any payload and id can need: one per 4 bits after the first 5 of the stuffed region,
    floor((L − 1)/4) for a region of L bits (Tindell, Burns & Wellings 1995, for classic CAN)."""
    if not fd:
        region = (54 if extended else 34) + 8 * length
        return region + (region - 1) // 4 + TAIL_BITS, 0
    arbitration = 36 if extended else 17
    region = arbitration + 5 + 8 * length
    stuffed = (region - 1) // 4
    stuffed_a = (arbitration - 1) // 4
    nominal = arbitration + stuffed_a + TAIL_BITS
    fast = 5 + 8 * length + stuffed - stuffed_a + _fd_crc_field(length)
    return (nominal, fast) if brs else (nominal + fast, 0)
