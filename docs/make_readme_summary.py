"""Rewrite the README's sample run summary from a real run of the quick start.

    python docs/make_readme_summary.py           # run the quick start, rewrite README.md's summary block
    python docs/make_readme_summary.py --print   # run it and print the block, README.md untouched

The block lies between ``<!-- summary:begin -->`` and ``<!-- summary:end -->`` in README.md. The run is the
quick start's command as a user types it (``warp-verlet run scenes/swinging_cloth.toml --preview``), in an
empty temporary directory with ``scenes`` linked to this checkout's, so that the summary names the same
relative paths the user sees; only ``--device cpu`` is added, so that the sample is a CPU run, which
tests/test_readme.py can repeat and check on any machine. Its files are thrown away with the directory.

The functions here are shared with tests/test_readme.py, so that the test reads the block as it is written.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import os
import platform
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
README = REPO / "README.md"
BEGIN, END = "<!-- summary:begin -->", "<!-- summary:end -->"
QUICK_START = ("run", "scenes/swinging_cloth.toml", "--preview")  # after `warp-verlet`, as the README shows it
SAMPLE_DEVICE = ("--device", "cpu")
# "key   value": the key is everything before the first run of two or more spaces ("stretch |D-L|/L" has spaces).
_LINE = re.compile(r"^(\S+(?: \S+)*?)\s{2,}(.*)$")
_BLOCK = re.compile(re.escape(BEGIN) + r"\n(.*?)\n" + re.escape(END), re.S)
_FENCE = re.compile(r"```text\n(.*?)\n```", re.S)


def quick_start_command() -> str:
    """The quick start as the README's shell block shows it."""
    return "warp-verlet " + " ".join(QUICK_START)


def run_quick_start(workdir: Path, preview: bool = True) -> str:
    """Run the quick start on the CPU in ``workdir`` (empty; ``scenes`` is linked there) and return its stdout:
    the run summary (and the preview's line). Raises RuntimeError, with the run's stderr, if it fails."""
    (workdir / "scenes").symlink_to(REPO / "scenes", target_is_directory=True)
    args = [a for a in QUICK_START if preview or a != "--preview"]
    command = [sys.executable, "-m", "warp_verlet", *args, *SAMPLE_DEVICE]
    done = subprocess.run(command, cwd=workdir, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    return done.stdout


def parse_summary(text: str) -> dict[str, str]:
    """The summary's lines as {key: value}, in order; a line that is not ``key  value`` is an error."""
    lines = {}
    for line in text.strip().splitlines():
        match = _LINE.match(line)
        if match is None:
            raise ValueError(f"not a summary line (key, two or more spaces, value): {line!r}")
        lines[match[1]] = match[2].strip()
    return lines


def readme_summary(readme_text: str) -> str:
    """The summary text of the README's block (inside its ```text fence)."""
    block = _BLOCK.search(readme_text)
    if block is None:
        raise ValueError(f"README.md has no {BEGIN} ... {END} block")
    fence = _FENCE.search(block[1])
    if fence is None:
        raise ValueError("the README's summary block has no ```text fence")
    return fence[1]


def machine() -> str:
    """The CPU, its logical CPU count, the OS and Warp's version, for the note under the block."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        warp = f", Warp {importlib.metadata.version('warp-lang')}"
    except importlib.metadata.PackageNotFoundError:
        warp = ""
    return f"{model}, {os.cpu_count()} logical CPUs, {platform.system()}{warp}"


def block(summary: str, where: str, day: datetime.date) -> str:
    """The README's block, markers included."""
    command = quick_start_command() + " " + " ".join(SAMPLE_DEVICE)
    return (f"{BEGIN}\n```text\n{summary.strip()}\n```\n\n"
            f"<sub>`{command}` on {where}, {day.isoformat()}; written by `python docs/make_readme_summary.py`. "
            "The wall-time lines differ from machine to machine; tests/test_readme.py checks every other line "
            f"against a run.</sub>\n{END}")


def with_block(readme_text: str, new_block: str) -> str:
    if _BLOCK.search(readme_text) is None:
        raise ValueError(f"README.md has no {BEGIN} ... {END} block to replace")
    return _BLOCK.sub(lambda _: new_block, readme_text, count=1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--print", action="store_true", help="print the block instead of rewriting README.md")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="readme-summary-") as workdir:
        summary = run_quick_start(Path(workdir))
    parse_summary(summary)  # refuse to write what the test could not read
    new_block = block(summary, machine(), datetime.date.today())
    if args.print:
        print(new_block)
        return 0
    README.write_text(with_block(README.read_text(encoding="utf-8"), new_block), encoding="utf-8")
    print(f"rewrote the summary block of {README}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
