"""The README shows what the code does: its sample run summary is the quick start's own run, its torn-stick
counts are the runs', and its Python example runs.

docs/make_readme_summary.py writes the summary block from a real run of the quick start; these tests run the
same scene, every frame of it, and compare. The lines that measure time (wall, start-up and compile time) and
the preview's line (the test does not render) are left out; every other line must match exactly, except the
stretch, which must agree to 2 significant figures (CPUs may round a last digit differently)."""

from __future__ import annotations

import importlib.util
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("make_readme_summary", REPO / "docs" / "make_readme_summary.py")
summary_tool = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(summary_tool)

VARYING = {"wall", "startup", "compile", "preview"}  # timings, and the render the test skips
STRETCH = "stretch |D-L|/L"
_NUMBERS = re.compile(r"max ([-+.\deE]+), rms ([-+.\deE]+)")


def readme_text() -> str:
    return (REPO / "README.md").read_text(encoding="utf-8")


def agree_to_2_significant_figures(run: float, shown: float) -> bool:
    """Within half a unit of the second significant figure of the README's value."""
    if shown == 0.0:
        return run == 0.0
    unit = 10.0 ** (math.floor(math.log10(abs(shown))) - 1)
    return abs(run - shown) <= 0.5 * unit


def compare(shown: dict[str, str], run: dict[str, str]) -> list[str]:
    """What differs between the README's summary and a run's, on the lines that do not vary."""
    problems = []
    keys_shown, keys_run = set(shown) - VARYING, set(run) - VARYING
    for key in sorted(keys_shown ^ keys_run):
        where = "the README" if key in keys_shown else "the run"
        problems.append(f"line {key!r} only in {where}")
    for key in sorted(keys_shown & keys_run):
        a, b = shown[key], run[key]
        if key == STRETCH:
            ma, mb = _NUMBERS.search(a), _NUMBERS.search(b)
            if ma is None or mb is None:
                problems.append(f"{key}: cannot read max and rms in {a!r} / {b!r}")
                continue
            for name, x, y in (("max", float(ma[1]), float(mb[1])), ("rms", float(ma[2]), float(mb[2]))):
                if not agree_to_2_significant_figures(y, x):
                    problems.append(f"{key} {name}: README {x:.3e}, run {y:.3e}")
        elif key == "device":  # the relaxation's thread count follows the cores; the result does not
            if a.split(" (relaxation")[0] != b.split(" (relaxation")[0]:
                problems.append(f"device: README {a!r}, run {b!r}")
        elif a != b:
            problems.append(f"{key}: README {a!r}, run {b!r}")
    return problems


def test_the_readme_quick_start_is_the_command_the_summary_comes_from():
    shell_lines = [line.strip() for block in re.findall(r"```sh\n(.*?)```", readme_text(), re.S)
                   for line in block.splitlines()]
    assert summary_tool.quick_start_command() in shell_lines


@pytest.mark.slow
def test_the_readme_summary_is_a_real_run_of_the_quick_start(tmp_path):
    shown = summary_tool.parse_summary(summary_tool.readme_summary(readme_text()))
    assert shown.get("device", "").startswith("cpu"), "the README's sample must be a CPU run: run " \
                                                     "python docs/make_readme_summary.py"
    for key in ("scene", "frames", "simulated", "particles", "sticks", "colours", STRETCH):
        assert key in shown, f"the README's summary has no {key!r} line"
    run = summary_tool.parse_summary(summary_tool.run_quick_start(tmp_path, preview=False))
    problems = compare(shown, run)
    assert not problems, ("the README's summary is not what the quick start gives; run python "
                          "docs/make_readme_summary.py:\n" + "\n".join(problems))


def test_the_comparison_catches_a_changed_line():
    """The comparison itself: each kind of difference the README could drift by is reported."""
    shown = {"scene": "scenes/swinging_cloth.toml", "device": "cpu", "particles": "4096", "wall": "1.0 s",
             STRETCH: "max 3.734e-03, rms 2.269e-04 (structural sticks, last frame)"}
    assert compare(shown, dict(shown, wall="9.9 s", startup="0.4 s")) == []
    assert compare(shown, dict(shown, device="cpu (relaxation on 2 threads)")) == []
    assert compare(shown, dict(shown, particles="4097"))
    assert compare(shown, dict(shown, **{"torn sticks": "3 of 23938"}))
    assert compare(shown, dict(shown, **{STRETCH: "max 3.734e-03, rms 2.4e-04 (structural sticks, last frame)"}))
    assert not compare(shown, dict(shown, **{STRETCH: "max 3.7341e-03, rms 2.27e-04 (structural sticks, last frame)"}))


@pytest.mark.slow
def test_the_readme_python_example_runs():
    blocks = re.findall(r"```python\n(.*?)```", readme_text(), re.S)
    assert blocks, "the README has no Python example"
    done = subprocess.run([sys.executable, "-c", blocks[0]], cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert re.search(r"StretchStats\(max=[-+.\deE]+, rms=[-+.\deE]+\)", done.stdout), done.stdout


@pytest.mark.slow
def test_the_readme_torn_counts_are_the_runs(tmp_path):
    """Each "(N sticks torn)" under a shipped scene's picture is what `warp-verlet run scenes/NAME.toml --device cpu
    -q` reports, as the README says."""
    counts = re.findall(r"`(\w+)`: [^|]*?\((\d+) sticks torn\)", readme_text())
    assert len(counts) >= 2, "the README's pictures name no torn counts"
    for name, shown in counts:
        command = [sys.executable, "-m", "warp_verlet", "run", f"scenes/{name}.toml", "--device", "cpu", "-q",
                   "-o", str(tmp_path / f"{name}.usdc")]
        done = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        torn = summary_tool.parse_summary(done.stdout)["torn sticks"]
        assert torn.split()[0] == shown, f"{name}: the README says {shown} sticks torn, the run {torn}"


@pytest.mark.parametrize("text", ["no block here", "<!-- summary:begin -->\nno fence\n<!-- summary:end -->"])
def test_a_readme_without_a_readable_block_is_refused(text):
    with pytest.raises(ValueError):
        summary_tool.readme_summary(text)
