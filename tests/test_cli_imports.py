"""What a ``cosim`` command imports: python-can without its MF4 support (asammdf with pandas, half
a second of every command and of every node's start-up where the export extra is installed), while
asammdf stays importable for cosim's own MF4 export."""

from __future__ import annotations

import subprocess
import sys

CHECK = """
import sys
from cosim import cli
assert cli.main(["dbc", "--out", sys.argv[1]]) == 0
print("can" in sys.modules, "asammdf" in sys.modules, "pandas" in sys.modules)
import asammdf  # cosim export --to mf4 imports it itself
print(asammdf.__name__)
"""


def test_a_command_imports_python_can_without_asammdf_and_asammdf_still_imports(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", CHECK, str(tmp_path / "bus.dbc")], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["True", "False", "False", "asammdf"]
