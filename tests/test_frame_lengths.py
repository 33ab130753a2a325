"""CAN frame lengths (cosim.bus.timing): worked by hand, the CRC-15 table against its bit-serial
definition, and the exact lengths against a literal bit walk and the worst case."""

from __future__ import annotations

import math
import random

from cosim.bus.timing import TAIL_BITS, crc15, frame_bits, frame_bits_worst_case, stuff_bits


def naive_bits(can_id: int, extended: bool, fd: bool, brs: bool, dlc: int, data: bytes) -> tuple[int, int]:
    """The same frame lengths from explicit bit lists, a bit-serial CRC and a literal stuffing walk."""

    def field(value, width):
        return [(value >> i) & 1 for i in range(width - 1, -1, -1)]

    # SOF, then the id: ID-A, SRR = 1, IDE = 1, ID-B (29 bits) or ID (11 bits)
    head = [0] + (field(can_id >> 18, 11) + [1, 1] + field(can_id & 0x3FFFF, 18) if extended else field(can_id, 11))
    payload = [bit for byte in data for bit in field(byte, 8)]
    if not fd:  # RTR, IDE (11-bit) or r1 (29-bit), r0, DLC, data, CRC
        region = head + [0, 0, 0] + field(dlc, 4) + payload
        crc = 0
        for bit in region:
            feedback = bit ^ (crc >> 14)
            crc = ((crc << 1) & 0x7FFF) ^ (0x4599 if feedback else 0)
        region += field(crc, 15)
        return len(region) + walk(region)[0] + 13, 0
    arbitration = head + ([0] if extended else [0, 0]) + [1, 0, int(brs)]  # RRS, (IDE), FDF, res, BRS
    data_phase = [0] + field(dlc, 4) + payload  # ESI, DLC, data
    stuffed_a, run_ = walk(arbitration)
    stuffed_d, _ = walk(data_phase, run_)
    crc_field = 4 + (17 if len(data) <= 16 else 21)
    crc_field += math.ceil(crc_field / 4)
    nominal, fast = len(arbitration) + stuffed_a + 13, len(data_phase) + stuffed_d + crc_field
    return (nominal, fast) if brs else (nominal + fast, 0)


def walk(bits: list[int], run_: tuple[int, int] = (-1, 0)) -> tuple[int, tuple[int, int]]:
    last, length = run_
    stuffed = 0
    for bit in bits:
        length = length + 1 if bit == last else 1
        last = bit
        if length == 5:
            stuffed += 1
            last, length = 1 - bit, 1
    return stuffed, (last, length)


def test_frame_lengths_worked_by_hand():
    # Classic, id 0, no data: 19 zero bits and CRC 0: 34 zeros, a stuff bit after every 5: 6.
    assert crc15(0, 19) == 0
    assert frame_bits(0x000, False, False, False, 0, b"") == (34 + 6 + TAIL_BITS, 0)
    assert frame_bits_worst_case(False, False, False, 0) == (34 + 8 + 13, 0)
    assert frame_bits_worst_case(False, False, False, 8) == (135, 0)  # the textbook 8-byte frame: 111 + 24
    # CAN FD, id 0x100, BRS, 8 zero bytes. Arbitration 0 00100000000 0 0 1 0 1: ten zeros after the
    # id's one: 2 stuff bits; 17 + 2 + 13 = 32 nominal bits. Data phase: ESI 0, DLC 1000 and 64 zeros:
    # 67 zeros after the one, 13 stuff bits; 5 + 64 + 13 + CRC field (4 + 17 + 6 fixed stuff bits) = 109.
    assert frame_bits(0x100, False, True, True, 8, bytes(8)) == (32, 109)
    assert frame_bits(0x100, False, True, False, 8, bytes(8)) == (141, 0)


def test_crc15_table_matches_the_bit_serial_definition():
    rng = random.Random(1)
    for _ in range(200):
        length = rng.randrange(1, 100)
        bits = rng.getrandbits(length)
        crc = 0
        for i in range(length - 1, -1, -1):
            feedback = ((bits >> i) & 1) ^ (crc >> 14)
            crc = ((crc << 1) & 0x7FFF) ^ (0x4599 if feedback else 0)
        assert crc15(bits, length) == crc


def test_exact_lengths_match_a_literal_walk_and_never_exceed_the_worst_case():
    rng = random.Random(2)
    sizes = {0: 0, 1: 1, 8: 8, 9: 12, 13: 32, 15: 64}
    for _ in range(600):
        extended, fd = rng.random() < 0.3, rng.random() < 0.5
        brs = fd and rng.random() < 0.7
        dlc = rng.choice(list(sizes)) if fd else rng.randrange(9)
        n = sizes.get(dlc, dlc)
        pattern = rng.choice(
            [lambda: rng.randrange(256), lambda: rng.choice([0, 255]), lambda: rng.choice([0x0F, 0xF0, 0x55])]
        )
        data = bytes(pattern() for _ in range(n))
        can_id = rng.getrandbits(29 if extended else 11)
        exact = frame_bits(can_id, extended, fd, brs, dlc, data)
        assert exact == naive_bits(can_id, extended, fd, brs, dlc, data), (can_id, extended, fd, brs, dlc, data.hex())
        worst = frame_bits_worst_case(extended, fd, brs, n)
        assert sum(exact) <= sum(worst)
    assert stuff_bits(0b11111, 5) == (1, 1 + 0)  # a run of five ones: one stuff bit (a zero starts the next run)
