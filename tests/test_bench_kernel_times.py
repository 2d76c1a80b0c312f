"""bench.kernel_times builds each of its scenes and times a frame (empty tables on the CPU, which has no activity
timing): the commands the results cite keep working."""

import pytest

from bench import kernel_times


@pytest.mark.parametrize("scene, frame", [("folded_drop", 15), ("drape_global", 26)])
def test_each_contact_scene_runs_to_its_timed_frame(scene, frame, capsys):
    assert kernel_times.main(["--device", "cpu", "--scene", scene, "--size", "8", "--budget", "2x1"]) == 0
    assert f"8^2 {scene} 2x1, frame {frame}: " in capsys.readouterr().out


def test_the_hanging_sheet_is_timed_in_every_sticks_form(capsys):
    assert kernel_times.main(["--device", "cpu", "--size", "8", "--budget", "2x1"]) == 0
    out = capsys.readouterr().out
    for form in ("explicit", "auto", "implicit", "tiled"):
        assert f"8^2 2x1 {form}: " in out
