"""bench/fuzz.py: its outcomes (finite, refused, a finding), its seeds, and the scenes it found that went to NaN,
which must stay finite."""

from __future__ import annotations

import numpy as np
import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import fuzz
from warp_verlet.core.simulator import Simulator

SMALL = {"simulation": {"fps": 60, "frames": 2, "substeps": 2, "iterations": 2},
         "cloth": [{"name": "c", "resolution": [4, 4], "size": [0.3, 0.3], "pins": ["top-left"]}]}


def scene_of(kind: str, seed: int, index: int) -> dict:
    rng = np.random.default_rng(seed)
    for _ in range(index):
        fuzz.KINDS[kind](rng)
    return fuzz.KINDS[kind](rng)


def test_a_sound_scene_is_finite_and_a_bad_one_refused():
    assert fuzz.run_scene(SMALL, 2) == "finite"
    bad = {**SMALL, "cloth": [{**SMALL["cloth"][0], "resolution": [0, 4]}]}
    assert fuzz.run_scene(bad, 2).startswith("refused: ")


def test_a_run_that_ends_non_finite_is_a_finding(monkeypatch):
    monkeypatch.setattr(Simulator, "positions", lambda self: np.full((16, 3), np.nan, np.float32))
    outcome = fuzz.run_scene(SMALL, 2)
    assert outcome == "non-finite at frame 0" and fuzz.is_finding(outcome)


def test_threads_that_end_elsewhere_than_one_thread_are_a_finding(monkeypatch):
    threaded = {**SMALL, "simulation": {**SMALL["simulation"], "frames": 3}}
    assert fuzz.run_scene(threaded, 3, threads=2) == "finite"  # captured on two threads, one thread's positions
    original = Simulator.positions
    monkeypatch.setattr(Simulator, "positions",
                        lambda self: original(self) + (1e-3 if self.threads > 1 else 0.0))
    outcome = fuzz.run_scene(threaded, 3, threads=2)
    assert outcome.startswith("threads differ: 2 threads end 0.001 m") and fuzz.is_finding(outcome)


def test_the_project_calling_itself_wrongly_is_a_finding_and_a_refusal_to_go_on_is_not(monkeypatch):
    from warp_verlet.errors import ArgumentError, WarpVerletError

    def wrong_call(self):
        raise ArgumentError("every phase needs one entry per thread")

    monkeypatch.setattr(Simulator, "step_frame", wrong_call)
    outcome = fuzz.run_scene(SMALL, 2)
    assert outcome == "error: ArgumentError: every phase needs one entry per thread" and fuzz.is_finding(outcome)

    def out_of_memory(self):
        raise WarpVerletError("the scene needs 90 GiB, but cuda:0 has only 80 GiB free")

    monkeypatch.setattr(Simulator, "step_frame", out_of_memory)
    outcome = fuzz.run_scene(SMALL, 2)
    assert outcome.startswith("stopped: ") and not fuzz.is_finding(outcome)


def test_with_a_cache_the_scene_runs_as_warp_verlet_run_does_and_its_cache_is_validated(tmp_path, monkeypatch):
    assert fuzz.run_scene(SMALL, 2, cache=tmp_path / "a.usdc") == "finite"
    assert list(tmp_path.iterdir()) == []  # the cache is removed once validated
    from warp_verlet.output import usd_writer
    monkeypatch.setattr(usd_writer, "validate_cache", lambda path: ["a bad cache"])
    outcome = fuzz.run_scene(SMALL, 2, cache=tmp_path / "b.usda")
    assert outcome == "invalid cache: a bad cache" and fuzz.is_finding(outcome)


def test_a_stick_form_asked_for_refuses_what_it_cannot_take_and_runs_the_rest(monkeypatch):
    from warp_verlet.errors import ArgumentError

    assert fuzz.run_scene(SMALL, 2, sticks="clustered") == "finite"
    tearing = {**SMALL, "cloth": [{**SMALL["cloth"][0], "tear_threshold": 2.0}]}
    outcome = fuzz.run_scene(tearing, 2, sticks="clustered")
    assert outcome.startswith("refused: sticks = 'clustered'") and not fuzz.is_finding(outcome)
    assert fuzz.run_scene(tearing, 2) == "finite"  # "auto" takes the scene as it is

    def wrong_call(self):
        raise ArgumentError("every phase needs one entry per thread")

    monkeypatch.setattr(Simulator, "step_frame", wrong_call)
    assert fuzz.is_finding(fuzz.run_scene(SMALL, 2, sticks="clustered"))  # not the form's refusal: a finding


def test_the_command_writes_its_counts(tmp_path):
    assert fuzz.main(["--kind", "lines", "--seed", "3", "--scenes", "2", "--frames", "1", "--cache",
                      "--out", str(tmp_path)]) == 0
    text = (tmp_path / "fuzz-lines-3-cache.md").read_text()
    assert "| lines | 3 | 2 | 1 | written and validated |" in text


@pytest.mark.parametrize("kind", list(fuzz.KINDS))
def test_a_seed_gives_the_same_scenes(kind):
    assert scene_of(kind, 5, 3) == scene_of(kind, 5, 3)
    assert scene_of(kind, 5, 3) != scene_of(kind, 6, 3)


@pytest.mark.parametrize("kind, seed, index", [
    ("lines", 1, 21),  # a line held along itself by the ground: an exact zero pivot (kernels/line_solve.py)
    ("lines", 1, 29),
    ("lines", 1, 59),
    ("extreme", 21, 222),  # a light strip stretched in the air: the overshoot limit read the rest area only
])
def test_the_scenes_it_found_going_to_nan_stay_finite(kind, seed, index):
    data = scene_of(kind, seed, index)
    assert fuzz.run_scene(data, data["simulation"]["frames"]) == "finite"


def test_the_input_kind_makes_shipped_scenes_wrong_and_the_loader_names_what_it_refuses():
    """Each input scene is a shipped scene with one to three values wrong, a key removed or an unknown one added:
    most are refused, each with one message naming the scene and the key; the rest load."""
    rng = np.random.default_rng(7)
    outcomes = [fuzz.run_scene(fuzz.input_scene(rng), 1) for _ in range(12)]
    refused = [o for o in outcomes if o.startswith("refused: ")]
    assert len(refused) >= 6 and all(o.startswith("refused: <fuzz>: ") for o in refused)
    assert not any(fuzz.is_finding(o) for o in outcomes)
