"""Every built-in scenario at seed 0 puts the same participant frames on the bus as when the
digests were recorded (``tests/frame_digests.py``): refactorings change no frame."""

from __future__ import annotations

import pytest

from cosim import scenario
from tests.frame_digests import log_digest, recorded, run_digest

RECORDED = recorded()


def test_every_builtin_scenario_has_a_recorded_digest():
    assert sorted(RECORDED) == scenario.builtin_names()


#: The papers' scenarios, which tests/test_reproductions.py runs with node processes: their digests
#: are checked on that one run (the frames are the same on either bus), the others' in-process.
PAPERS = ("cdc2016-ex1", "cdc2016-ex2", "tac2024-s1-constant", "tac2024-s1-timevarying", "tac2024-s2-p4")


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(RECORDED))
def test_frames_match_the_recorded_digest(name, builtin_run):
    if name in PAPERS:
        result = builtin_run(name)
        assert result.status == "completed", result.error
        digest, count = log_digest(result.path)
    else:
        digest, count = run_digest(name)
    assert (digest, count) == (RECORDED[name]["sha256"], RECORDED[name]["frames"]), (
        f"{name}: the participant frames changed; if on purpose, run 'python -m tests.frame_digests --update' and say "
        "why"
    )
