""".ci/readme_commands.sh, which CI runs on the base install, holds the README's commands for a user: the lines of the
README's ```sh blocks in their order, less the installs (`pip install ...`: CI installs the base package itself) and
the test command (`pytest`, which CI runs after installing the test extras). A README that gains, loses, reorders or
edits a command and a script that does not follow fail here."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SH_BLOCK = re.compile(r"^```(?:sh|bash|shell|console)[ \t]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def _command(line: str) -> str:
    """A shell line without its trailing comment and surrounding space ('' for a comment or a blank line)."""
    return re.sub(r"(^|\s)#.*$", "", line).strip()


def readme_commands(readme: str) -> list[str]:
    """The user's commands of a README: each line of its ```sh blocks, but installs and the test command."""
    lines = [_command(line) for block in SH_BLOCK.findall(readme) for line in block.splitlines()]
    return [line for line in lines if line and not line.startswith("pip install") and "pytest" not in line.split()]


def script_commands(script: str) -> list[str]:
    """The commands of .ci/readme_commands.sh: its lines but comments, blanks and the shell's own settings."""
    lines = [_command(line) for line in script.splitlines()]
    return [line for line in lines if line and not line.startswith("set -")]


def test_ci_runs_the_readmes_commands_in_order():
    readme = readme_commands((ROOT / "README.md").read_text(encoding="utf-8"))
    assert readme, "the README has no user commands in ```sh blocks"
    assert script_commands((ROOT / ".ci" / "readme_commands.sh").read_text(encoding="utf-8")) == readme


def test_the_extraction_keeps_commands_and_drops_installs_tests_and_comments():
    readme = "\n".join([
        "Install:", "```sh", "pip install .", "```", "Run:", "```sh",
        "warp-verlet run scenes/a.toml --preview      # writes a.usdc", "# a comment", "",
        "warp-verlet preview a.usdc -o a.png", "```", "```text", "warp-verlet run not-a-command", "```",
        "```toml", "frames = 1", "```", "```sh", 'pip install ".[test]" && pytest', "```",
    ])
    assert readme_commands(readme) == ["warp-verlet run scenes/a.toml --preview", "warp-verlet preview a.usdc -o a.png"]
    assert script_commands("#!/usr/bin/env bash\nset -euo pipefail\n\nwarp-verlet validate a.toml  # check\n") == [
        "warp-verlet validate a.toml"]
