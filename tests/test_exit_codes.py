"""Every exit code the command line documents (warp_verlet/apps/cli.py's docstring), one test each; where another file
already tests a code end to end, this one names it rather than run it twice:

- 0 success: tests/test_cli.py::test_run_writes_a_valid_cache_with_every_frame, ::test_validate_command
- 2 invalid scene: tests/test_cli.py::test_invalid_scene_exits_nonzero_names_the_key_and_writes_nothing
- 2 invalid cache: tests/test_preview.py::test_bad_inputs_exit_2_with_one_message_naming_the_file,
  tests/test_web_cli.py::test_view_refuses_what_is_not_a_cache
- 2 invalid arguments: tests/test_cli.py::test_threads_are_bounded_with_a_message_about_threads; here: the output's
  name, the device's name
- 2 a port in use: tests/test_web_cli.py::test_a_port_in_use_is_one_clear_error
- 1 divergence: tests/test_cli.py::test_divergence_stops_names_the_frame_and_keeps_frames_done
- 1 unwritable output: tests/test_cli.py::test_unwritable_output_fails_before_simulating
- 1 busy output: tests/test_output_safety.py::test_a_second_run_to_the_same_output_is_refused_at_once
- 1 full disk: tests/test_output_safety.py::test_a_cache_that_cannot_fit_is_refused_before_anything_is_written
- 1 missing device: here
- 130 interrupted: tests/test_cli.py::test_ctrl_c_leaves_a_valid_cache_of_the_frames_done
- 143 terminated: tests/test_output_safety.py::test_sigterm_stops_like_ctrl_c_and_says_where_the_frames_are
- 141 standard output closed: here
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from test_cli import SCENE
from warp_verlet.apps.cli import STDOUT_CLOSED, main


@pytest.fixture
def work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "small.toml").write_text(SCENE)
    return tmp_path


@pytest.mark.parametrize("output, words", [
    ("out.txt", "the file name must end in .usd, .usda, .usdc"),
    ("out", "the file name must end in"),
    ("small.partial.usdc", "names ending in .partial.usdc are kept for the frames of runs that did not finish"),
    ("small.toml.usda", None),  # a good name: the control
])
def test_an_output_name_that_cannot_be_a_cache_is_a_bad_argument(work, output, words, capsys):
    rc = main(["run", "small.toml", "-o", output, "--device", "cpu", "-q", "--frames", "1"])
    err = capsys.readouterr().err
    if words is None:
        assert rc == 0, err
        return
    assert rc == 2 and f"error: cannot write {output}: {words}" in err
    assert sorted(p.name for p in work.iterdir()) == ["small.toml"]  # nothing simulated, nothing written


def test_an_output_that_is_an_input_is_a_bad_argument(work, capsys):
    assert main(["run", "small.toml", "-o", "small.toml", "--device", "cpu", "-q"]) == 2
    assert "the output would overwrite the input file" in capsys.readouterr().err


def test_a_device_name_of_another_form_is_a_bad_argument(work, capsys):
    for bad in ("gpu", "cuda:x", "CPU", "cuda:"):
        with pytest.raises(SystemExit) as caught:
            main(["run", "small.toml", "--device", bad])
        assert caught.value.code == 2
        assert f"argument --device: expected cpu, cuda or cuda:N, got {bad!r}" in capsys.readouterr().err
    assert not (work / "small.usdc").exists()


def test_a_device_this_machine_lacks_fails_the_run(work, capsys):
    # cuda:99: no CUDA at all on a CPU machine, an index past the count on a GPU one; either way the run fails.
    assert main(["run", "small.toml", "--device", "cuda:99", "-q"]) == 1
    err = capsys.readouterr().err
    assert "error: device 'cuda:99'" in err and "Traceback" not in err
    assert not (work / "small.usdc").exists()


def closed_stdout_run(args: list[str], cwd) -> subprocess.CompletedProcess:
    """The command with a standard output whose reader is already gone (as `| head -1` leaves it once head
    has exited): every write to it fails with EPIPE."""
    read, write = os.pipe()
    os.close(read)
    try:
        return subprocess.run([sys.executable, "-m", "warp_verlet", *args], cwd=cwd, stdout=write,
                              stderr=subprocess.PIPE, text=True)
    finally:
        os.close(write)


@pytest.mark.slow
@pytest.mark.parametrize("args, code", [
    (["validate", "small.toml"], STDOUT_CLOSED),
    (["run", "small.toml", "--device", "cpu", "-q", "--frames", "1"], STDOUT_CLOSED),
])
def test_a_closed_standard_output_ends_quietly(work, args, code):
    done = closed_stdout_run(args, work)
    assert STDOUT_CLOSED == 141 and done.returncode == code
    assert done.stderr == "", done.stderr  # no traceback, no "Exception ignored"
    if args[0] == "run":  # the run itself finished: only its summary had nowhere to go
        assert (work / "small.usdc").is_file()


def test_a_bad_output_name_is_refused_before_warp_starts(work):
    probe = ("import sys; from warp_verlet.apps.cli import main; rc = main(['run', 'small.toml', '-o', 'out.txt', '-q']); "
             "print(rc, 'warp' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", probe], cwd=work, capture_output=True, text=True, check=True)
    assert done.stdout.split()[-2:] == ["2", "False"], done.stderr
