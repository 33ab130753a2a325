"""Every built-in scenario at seed 0 puts the same participant frames on the bus as when the
digests were recorded (``tests/frame_digests.py``): refactorings change no frame."""

from __future__ import annotations

import pytest

from cosim import scenario
from tests.frame_digests import recorded, run_digest

RECORDED = recorded()


def test_every_builtin_scenario_has_a_recorded_digest():
    assert sorted(RECORDED) == scenario.builtin_names()


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(RECORDED))
def test_frames_match_the_recorded_digest(name):
    digest, count = run_digest(name)
    assert (digest, count) == (RECORDED[name]["sha256"], RECORDED[name]["frames"]), (
        f"{name}: the participant frames changed; if on purpose, run 'python -m tests.frame_digests --update' and say "
        "why"
    )
