"""The size of the product's rooms: functions over 60 lines, and files over 600 lines (tests too).

A room a newcomer can read in one sitting is a file of a few hundred lines whose functions fit on
a screen. ``python -m tests.sizes`` prints the offenders, longest first; ``tests/test_layout.py``
allows none but those listed in ``LONG_FUNCTIONS_KEPT``, each with the reason it is kept whole.

Lines are counted as they stand in the file (docstrings and comments included): what a reader
scrolls through. A function's lines are those of its ``def`` statement to its last line, nested
functions included.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PRODUCT = ("cosim", "estimators", "faults", "mjcf", "bench")
#: Where no file may pass ``LONG_FILE`` lines: the product and its tests (a test file is read, and
#: mended, as often as the code it checks).
SIZED = (*PRODUCT, "tests")
LONG_FUNCTION = 60
LONG_FILE = 600
#: The functions over ``LONG_FUNCTION`` lines kept whole (``path:name``), and why.
LONG_FUNCTIONS_KEPT: dict[str, str] = {}


@dataclass(frozen=True)
class Size:
    where: str
    """The file, and for a function ``file:name``."""
    lines: int
    line: int = 1


def product_files(root: Path = ROOT, packages: tuple[str, ...] = PRODUCT) -> list[Path]:
    return sorted(path for package in packages for path in (root / package).rglob("*.py"))


def long_files(root: Path = ROOT, packages: tuple[str, ...] = SIZED) -> list[Size]:
    sizes = [Size(str(p.relative_to(root)), len(p.read_text().splitlines())) for p in product_files(root, packages)]
    return sorted((s for s in sizes if s.lines > LONG_FILE), key=lambda s: -s.lines)


def long_functions(root: Path = ROOT) -> list[Size]:
    found = []
    for path in product_files(root):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno is not None:
                start = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                lines = node.end_lineno - start + 1
                if lines > LONG_FUNCTION:
                    found.append(Size(f"{path.relative_to(root)}:{node.name}", lines, node.lineno))
    return sorted(found, key=lambda s: -s.lines)


def main() -> int:
    for title, sizes in (
        (f"files over {LONG_FILE} lines", long_files()),
        (f"functions over {LONG_FUNCTION} lines", long_functions()),
    ):
        print(f"{title}: {len(sizes)}")
        for size in sizes:
            kept = f"  (kept: {LONG_FUNCTIONS_KEPT[size.where]})" if size.where in LONG_FUNCTIONS_KEPT else ""
            print(f"  {size.lines:5d}  {size.where} (line {size.line}){kept}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
