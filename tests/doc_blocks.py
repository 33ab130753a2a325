"""The fenced blocks of the README and the site's pages, with the marker that says what the test
suite does with each (docs/contributing.md spells the convention):

- ``<!-- run -->`` before a block: tests/test_docs.py runs it (``sh``: line by line in bash, in a fresh
  folder; ``python``: as a script) and it must succeed;
- ``<!-- output -->`` before the block that follows a run block: what it prints, checked line by line
  (in order, other lines in between allowed; ``…`` stands for any text within a line, and a line
  that is only ``…`` for lines left out);
- ``<!-- run by: tests/test_x.py::test_name ... -->``: an expensive block that named tests already run;
  each test must exist and, together, their source must hold the block's essential words
  (``essential_words``);
- ``<!-- not run: the reason -->``: a block the suite cannot run, and why.

A ``sh`` or ``python`` block without one of these is an error, as is a block of another language (or
none) that holds a command.
"""

from __future__ import annotations

import ast
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COMMAND_LANGUAGES = {"sh": "sh", "bash": "sh", "shell": "sh", "console": "sh", "python": "python", "py": "python"}
MARKER = re.compile(r"^<!--\s*(run|output|run by|not run)\s*(?::\s*(.*?))?\s*-->$")
FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")
# the first words of a line that is a command, in a block that claims to be text or data
COMMAND_START = re.compile(r"^(\$ )?(cosim |python3? |\.venv/bin/|pip |git |from cosim|import cosim)")


@dataclass(frozen=True)
class Block:
    """One fenced block: where it is, its language, its text and its marker (kind and argument)."""

    path: Path
    line: int
    language: str
    text: str
    marker: str | None
    argument: str

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"

    @property
    def kind(self) -> str | None:
        """``sh`` or ``python`` for a command block, None for text and data."""
        return COMMAND_LANGUAGES.get(self.language)


def documents() -> list[Path]:
    """The README and every page of the site."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def blocks(path: Path) -> list[Block]:
    """The fenced blocks of a Markdown file, in order, each with the marker on the line before it."""
    lines = path.read_text(encoding="utf-8").splitlines()
    found: list[Block] = []
    i = 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            i += 1
            continue
        indent, fence, language = opening.groups()
        end = i + 1
        while end < len(lines) and not lines[end].strip().startswith(fence[0] * len(fence)):
            end += 1
        text = "\n".join(line[len(indent) :] for line in lines[i + 1 : end])
        marker = MARKER.match(lines[i - 1].strip()) if i > 0 else None
        kind, argument = (marker.group(1), marker.group(2) or "") if marker else (None, "")
        found.append(Block(path, i + 1, language.lower(), text, kind, argument))
        i = end + 1
    return found


def all_blocks() -> list[Block]:
    return [block for path in documents() for block in blocks(path)]


def problems(block: Block, previous: Block | None) -> list[str]:
    """What is wrong with a block's marker, each said with where the block is and what to do."""
    if block.marker == "output":
        if previous is None or previous.marker != "run":
            return [f"{block.where}: an output block must follow a block marked <!-- run -->"]
        return []
    if block.kind is None:
        if block.marker in ("run", "run by"):
            return [f"{block.where}: a {block.language or 'plain'} block cannot be run; tag it sh or python"]
        looks = [line for line in block.text.splitlines() if COMMAND_START.match(line.strip())]
        if looks and block.marker != "not run":
            return [f"{block.where}: holds a command ({looks[0].strip()[:60]!r}): tag it sh or python and mark it"]
        return []
    if block.marker is None:
        return [
            f"{block.where}: a {block.language} block without a marker: put <!-- run -->, "
            "<!-- run by: tests/...::test_... -->, or <!-- not run: why --> on the line before it"
        ]
    if block.marker == "not run" and not block.argument:
        return [f"{block.where}: <!-- not run --> needs its reason: <!-- not run: why -->"]
    if block.marker == "run by":
        return run_by_problems(block)
    return []


def run_by_problems(block: Block) -> list[str]:
    """A run-by block's tests must exist and hold its essential words between them."""
    names = block.argument.split()
    if not names:
        return [f"{block.where}: <!-- run by: --> names no test"]
    sources: list[str] = []
    for name in names:
        source = test_source(name)
        if source is None:
            return [f"{block.where}: no test {name} (give tests/FILE.py::test_name)"]
        sources.append(source)
    words = essential_words(block)
    if not words:
        return [f"{block.where}: nothing in it for a test to stand for: <!-- run --> it, or <!-- not run: why -->"]
    missing = [word for word in words if not any(word in source for source in sources)]
    if missing:
        return [f"{block.where}: {' '.join(names)} does not run {', '.join(missing)}: name the tests that do"]
    return []


def test_source(name: str) -> str | None:
    """The source of ``tests/FILE.py::test_name`` (or ``::Class::test_name``), None if there is none."""
    file, _, qualified = name.partition("::")
    path = ROOT / file
    if not qualified or not path.is_file():
        return None
    text = path.read_text(encoding="utf-8")
    nodes: list[ast.stmt] = ast.parse(text).body
    found: ast.stmt | None = None
    for part in qualified.split("::"):
        found = next((node for node in nodes if getattr(node, "name", None) == part), None)
        if found is None:
            return None
        nodes = getattr(found, "body", [])
    return ast.get_source_segment(text, found) if found is not None else None


def essential_words(block: Block) -> list[str]:
    """What a test must do to stand for a block: for a command, its program (``cosim`` commands: the
    subcommand; ``python -m``: the module) and every option it gives; for Python, each name it imports."""
    if block.kind == "python":
        tree = ast.parse(block.text)
        imports = [node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom)]
        return [alias.asname or alias.name for node in imports for alias in node.names]
    words: list[str] = []
    for command in commands(block.text):
        tokens = [token.strip("[](){}") for token in shlex.split(command, comments=True)]
        tokens = [token for token in tokens if token and not re.match(r"^[A-Z_]+=", token)]  # VAR=value first
        if not tokens:
            continue
        program = tokens[0].rsplit("/", 1)[-1]
        if program == "cosim" and len(tokens) > 1:
            words.append(tokens[1])
        elif program.startswith("python") and tokens[1:2] == ["-m"]:
            words.append(tokens[2])
        elif not program.startswith("python"):
            words.append(program)
        words += [token.split("=", 1)[0] for token in tokens[1:] if token.startswith("-") and token != "-m"]
    return list(dict.fromkeys(words))


def commands(text: str) -> list[str]:
    """The commands of a shell block: continuation lines joined, split at ``&&``, ``;`` and ``|``."""
    joined = re.sub(r"\\\n\s*", " ", text)
    found: list[str] = []
    for line in joined.splitlines():
        line = line.split(" #", 1)[0].strip()
        if line and not line.startswith("#"):
            found += [part.strip() for part in re.split(r"&&|\|\||;|\|", line) if part.strip()]
    return found


def shown_lines_match(shown: str, printed: str) -> str | None:
    """None if every line of ``shown`` is in ``printed``, in order; else the first line that is not."""
    lines = [line.rstrip() for line in printed.splitlines()]
    at = 0
    for want in shown.splitlines():
        want = want.rstrip()
        if want.strip() in ("", "…"):
            continue
        pattern = re.compile(".*".join(re.escape(part) for part in want.split("…")) + "$")
        while at < len(lines) and not pattern.match(lines[at]):
            at += 1
        if at == len(lines):
            return want
        at += 1
    return None
