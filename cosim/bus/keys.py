"""The run's secret and the keys derived from it: one per sender and purpose.

Every run draws a secret (32 random bytes; ``COSIM_RUN_SECRET`` fixes it, to repeat a run's frames
bit for bit). It never leaves the runner: participants get the keys derived from it that they need,
in their private spec file or the private run registry. Two purposes: ``control`` keys sign the
control frames (``cosim.bus.control_frames``, every run), ``secoc`` keys the data frames
(``cosim.bus.secoc``, with ``[bus] authentication = "secoc"``).
"""

from __future__ import annotations

import os

from cosim.errors import CosimError

SECRET_ENV = "COSIM_RUN_SECRET"
"""A fixed run secret (64 hex digits) instead of a random one: a run's frames repeat bit for bit."""


def run_secret() -> bytes:
    """A run's secret: random, or ``COSIM_RUN_SECRET`` (64 hex digits) to repeat a run's frames."""
    fixed = os.environ.get(SECRET_ENV)
    if not fixed:
        return os.urandom(32)
    try:
        secret = bytes.fromhex(fixed)
    except ValueError:
        secret = b""
    if len(secret) != 32:
        raise CosimError(f"{SECRET_ENV} must be 64 hex digits (32 bytes), or unset for a random run secret")
    return secret


def derive_key(secret: bytes, sender: str, purpose: str = "secoc") -> bytes:
    """The sender's AES-128 key for ``purpose`` (``secoc``: its data frames; ``control``: its
    control frames, ``cosim.bus.control_frames``): HKDF-SHA256 of the run secret, with the purpose
    and the sender's name as info."""
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.kdf.hkdf import HKDF

    info = f"cosim {purpose} key {sender}".encode()
    return HKDF(hashes.SHA256(), 16, salt=None, info=info).derive(secret)
