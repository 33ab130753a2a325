"""The suite's groups hold under pytest-xdist (``--dist loadgroup``, as CI runs it): every test of
a file runs on one worker, and the files that read the built-in scenarios' runs on one, so that a
module's fixtures and a built-in run (minutes each) are made once."""

from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import pytest

from tests import conftest

ROOT = Path(__file__).resolve().parent.parent
LOADGROUP = ["-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2", "--dist", "loadgroup", "."]

#: A test that writes its module's name and its worker's to workers.txt
TEST = """
def test_{i}():
    with open("workers.txt", "a") as out:
        out.write(__name__ + " " + os.environ["PYTEST_XDIST_WORKER"] + "\\n")
"""


@pytest.mark.serial  # it starts two pytest-xdist workers of its own
def test_under_loadgroup_each_file_and_the_builtin_run_readers_run_on_one_worker(tmp_path):
    # The suite's own grouping hook, in a suite of four files: two of BUILTIN_RUN_READERS, two others
    (tmp_path / "conftest.py").write_text(
        f"import sys\nsys.path.insert(0, {str(ROOT)!r})\nimport pytest\nfrom tests import suite_groups\n\n\n"
        + inspect.getsource(conftest.pytest_collection_modifyitems)
    )
    body = "import os\n" + "".join(TEST.format(i=i) for i in range(4))
    for name in ("test_frame_digests.py", "test_reproductions.py", "test_one.py", "test_two.py"):
        (tmp_path / name).write_text(body)
    done = subprocess.run([sys.executable, *LOADGROUP], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    workers: dict[str, set[str]] = {}
    for line in (tmp_path / "workers.txt").read_text().splitlines():
        module, worker = line.split()
        workers.setdefault(module, set()).add(worker)
    assert all(len(found) == 1 for found in workers.values()), f"a file's tests ran on several workers: {workers}"
    assert workers["test_frame_digests"] == workers["test_reproductions"], workers
