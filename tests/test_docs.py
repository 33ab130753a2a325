"""The documentation cannot rot: the site builds with ``mkdocs build --strict`` (a broken link, a page
missing from the nav, an unresolved API reference fail it), and every command and Python block of the
README and the site runs here with the output it shows, or is marked with the test that runs it or
the reason it is not run (tests/doc_blocks.py, docs/contributing.md)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.doc_blocks import ROOT, Block, all_blocks, problems, shown_lines_match

pytestmark = pytest.mark.xdist_group("docs")  # the run blocks share one folder: one worker runs them in order


@pytest.mark.slow
def test_the_site_builds_strictly_with_its_api_reference_and_search(tmp_path):
    site = tmp_path / "site"
    command = ["mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"), "-d", str(site)]
    built = subprocess.run(
        [sys.executable, "-m", *command],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        timeout=300,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    api = (site / "api.html").read_text()
    contract = ("load_scenario", "Estimator", "Controller", "SensorFault", "ActuatorFault", "PlantInfo", "LinearModel")
    for name in contract:
        assert f'id="{name}' in api or f"{name}</code>" in api, f"the API reference lacks {name}"
    assert (site / "search" / "search_index.json").stat().st_size > 100_000  # every page indexed
    assert (site / "figures" / "vessel-isolability.png").exists()


def test_every_command_block_is_run_or_marked():
    found: list[str] = []
    for previous, block in zip([None, *all_blocks()], all_blocks()):
        found += problems(block, previous)
    assert not found, "\n".join(found)


def test_the_readme_starts_with_the_two_commands_and_ci_runs_the_second():
    readme = (ROOT / "README.md").read_text()
    first = all_blocks()[0]
    assert first.path.name == "README.md" and first.line <= 5 and first.marker == "not run"
    install, suite = first.text.splitlines()
    assert install == "python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/cosim run"
    assert suite in (ROOT / ".ci" / "run").read_text().splitlines()
    assert len(readme.splitlines()) <= 300
    links = re.findall(r"\]\(([^)#]+)[^)]*\)", readme)
    broken = [link for link in links if "://" not in link and not (ROOT / link).exists()]
    assert not broken, f"the README links to files that are not there: {broken}"


def run_block(block: Block, folder: Path) -> subprocess.CompletedProcess[str]:
    """A run block in ``folder``, this interpreter's ``cosim`` and ``python`` first on the PATH."""
    bin_dir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ["PATH"], "COLUMNS": "100", "NO_COLOR": "1"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    shell = ["bash", "-e", "-o", "pipefail", "-c", block.text]
    argv = shell if block.kind == "sh" else [sys.executable, "-c", block.text]
    # one stream: what a block prints, in the order a terminal shows it
    return subprocess.run(
        argv, cwd=folder, env=env, text=True, timeout=300, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )


@pytest.mark.slow
def test_the_run_blocks_run_and_print_what_they_show(tmp_path):
    """In the order of the pages, in one folder (a block may read what an earlier one wrote), which
    holds links to the repository's examples/ and scenarios/ as a checkout does; a block that
    appears twice (the README's tour, again in Get started) runs once."""
    for name in ("examples", "scenarios"):
        (tmp_path / name).symlink_to(ROOT / name)
    failures: list[str] = []
    done: dict[tuple[str, str], subprocess.CompletedProcess[str]] = {}
    blocks = all_blocks()
    for block, following in zip(blocks, [*blocks[1:], None]):
        if block.marker != "run":
            continue
        key = (block.kind or "", block.text)
        if key not in done:
            done[key] = run_block(block, tmp_path)
        ran = done[key]
        printed = ran.stdout
        if ran.returncode != 0:
            failures.append(f"{block.where}: exit status {ran.returncode}:\n{printed[-2000:]}")
        elif following is not None and following.marker == "output":
            missing = shown_lines_match(following.text, printed)
            if missing is not None:
                failures.append(f"{following.where}: not printed: {missing!r}; it printed:\n{printed[-3000:]}")
    assert not failures, "\n\n".join(failures)
