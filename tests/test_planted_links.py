"""Outputs are never written through a symbolic link planted at their name, or at the name of a
temporary: what the link points at is left as it was (cosim.files)."""

from __future__ import annotations

import os
import shutil

import pytest

from cosim import api
from cosim.analysis.export import export
from cosim.errors import CosimError
from cosim.files import open_output, temporary_beside
from cosim.log.recover import recover
from cosim.log.writer import McapLog


@pytest.fixture
def victim(tmp_path):
    """A file of the user's that a planted link points at."""
    path = tmp_path / "precious.txt"
    path.write_text("keep me")
    return path


def test_a_log_is_not_written_through_a_link_at_its_name(tmp_path, victim):
    (tmp_path / "run.mcap").symlink_to(victim)
    with pytest.raises(CosimError, match=r"run\.mcap is a symbolic link: cosim does not write through one"):
        McapLog(tmp_path / "run.mcap")
    with pytest.raises(CosimError, match="symbolic link"):
        api.run(api.load_scenario("masses-bias", {"duration": 0.5}), tmp_path / "run.mcap", in_process=True)
    assert victim.read_text() == "keep me"


def test_an_existing_file_is_replaced_only_when_asked(tmp_path):
    path = tmp_path / "out.bin"
    path.write_bytes(b"old")
    with pytest.raises(CosimError, match=r"out\.bin exists: choose another file, or pass --force to replace it"):
        open_output(path, replace=False)
    with open_output(path) as stream:
        stream.write(b"new")
    assert path.read_bytes() == b"new"


def test_temporaries_have_unpredictable_names_and_are_created_exclusively(tmp_path):
    first, second = temporary_beside(tmp_path / "x.mcap", ".part"), temporary_beside(tmp_path / "x.mcap", ".part")
    assert first != second and first.name.startswith(".x.mcap.") and first.suffix == ".part"
    assert first.stat().st_size == 0 and oct(first.stat().st_mode & 0o777) == oct(0o644)


def test_recover_and_export_ignore_links_at_their_old_temporary_names(default_run, tmp_path, victim):
    log = tmp_path / "run.mcap"
    shutil.copy(default_run.path, log)
    for old in (f".{log.name}.recovering", "run.csv.part.csv", "fixed.mcap"):
        os.symlink(victim, tmp_path / old)
    (tmp_path / "fixed.mcap").unlink()  # a link at the final name is replaced by the rename, not followed
    os.symlink(victim, tmp_path / "fixed.mcap")
    recovered = recover(log, tmp_path / "fixed.mcap")
    assert recovered.messages > 0 and not (tmp_path / "fixed.mcap").is_symlink()
    export(log, "csv", tmp_path / "run.csv")
    assert victim.read_text() == "keep me"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".run.") and not p.is_symlink()]  # none left
