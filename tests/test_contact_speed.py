"""The run's warning where self-colliding particles outran the contact (warp_verlet/apps/contact_speed.py): a layer
falling onto another faster than half the collision thickness a substep is named, with the substeps that hold it;
those substeps, or a cloth that falls as one piece, leave the summary quiet."""

import re

import numpy as np
import pytest

from warp_verlet.apps.contact_speed import SAFE_FRACTION, ContactSpeedWatch
from warp_verlet.apps.runner import run_scene
from warp_verlet.input.scene import parse_scene

SPACING = 0.5 / 11  # both cloths: 0.5 m, 12 x 12
THICKNESS = 0.8 * SPACING  # the default: 36 mm


def sheet(name: str, height: float) -> dict:
    return {"name": name, "resolution": [12, 12], "size": [0.5, 0.5], "origin": [-0.25, height, -0.25],
            "orientation": "horizontal", "mass": 0.1, "sticks": ["structural", "shear"], "self_collision": True}


def landing(substeps: int, frames: int = 30, cloths=None) -> dict:
    """A sheet lying on the ground and a second one dropped onto it from 0.6 m (about 3.4 m/s at the landing)."""
    return {"simulation": {"fps": 60, "frames": frames, "substeps": substeps, "iterations": 4},
            "cloth": cloths or [sheet("bottom", 0.03), sheet("top", 0.6)],
            "collider": [{"type": "plane", "name": "ground", "point": [0, 0, 0], "normal": [0, 1, 0],
                          "thickness": 0.005}]}


def summary_of(table: dict, tmp_path):
    return run_scene(parse_scene(table, file="<test>"), output=tmp_path / "out.usdc", device="cpu")


def test_a_layer_landing_faster_than_half_the_thickness_a_substep_is_named_with_the_substeps_that_hold_it(tmp_path):
    summary = summary_of(landing(substeps=2), tmp_path)
    text = summary.contact_speed
    assert text is not None and "'bottom', 'top'" in text and f"{THICKNESS * 1e3:.3g} mm" in text
    assert "warning" in summary.format() and text in summary.format()
    moved_mm = float(re.search(r"moved up to ([0-9.]+) mm", text).group(1))
    # About the top sheet's fall over a substep: 0.6 m at 60 fps and 2 substeps reaches 3.4 m/s, 28 mm a substep.
    assert SAFE_FRACTION * THICKNESS * 1e3 < moved_mm <= 3.5 / 120 * 1e3
    needed = int(re.search(r"substeps = (\d+)", text).group(1))
    assert needed == pytest.approx(2 * moved_mm / (SAFE_FRACTION * THICKNESS * 1e3), abs=1)
    # The advice holds: at the substeps it names, the same landing is under the limit.
    assert summary_of(landing(substeps=needed), tmp_path).contact_speed is None


def test_a_cloth_falling_as_one_piece_spreads_nothing_however_fast(tmp_path):
    # No collider and no other cloth: 30 frames of free fall reach 4.9 m/s, 41 mm a substep, above the limit of
    # 18 mm, but every particle moves alike, so no layer approaches another.
    table = landing(substeps=2, cloths=[sheet("alone", 1.0)])
    del table["collider"]
    summary = summary_of(table, tmp_path)
    assert summary.contact_speed is None
    assert "warning" not in summary.format()


def test_a_scene_without_self_collision_is_not_watched():
    scene = parse_scene(landing(substeps=2, cloths=[{**sheet("plain", 0.6), "self_collision": False}]), file="<t>")

    class Model:
        cloths = [type("Slot", (), {"first": 0})()]

    watch = ContactSpeedWatch(scene, Model())
    assert not watch.active
    watch.observe(1, np.zeros((144, 3)), 2)
    assert watch.advice() is None


def test_the_spread_is_of_moves_per_substep_between_particles_that_end_the_frame_near_each_other():
    scene = parse_scene(landing(substeps=2, cloths=[sheet("one", 0.6)]), file="<t>")

    class Model:
        cloths = [type("Slot", (), {"first": 0})()]

    watch = ContactSpeedWatch(scene, Model())
    rows, cols = np.meshgrid(np.arange(12) * SPACING, np.arange(12) * SPACING, indexing="ij")
    start = np.stack([cols.ravel(), np.zeros(144), rows.ravel()], axis=1)
    watch.observe(0, start, 4)
    moved = start - [0.0, 1.0, 0.0]  # all of them 1 m down: no spread
    moved[5, 1] -= 0.1  # one of them 0.1 m further, ending within a cell of its neighbours
    watch.observe(1, moved, 4)
    assert watch.worst == pytest.approx(0.1 / 4)
    assert watch.worst_frame == 1
    # The two halves 1 m apart in a frame: each half moves as one piece, and no particle of one ends near one
    # of the other, so nothing approached anything.
    apart = moved + np.where(start[:, :1] < 5.5 * SPACING, [-0.5, 0.0, 0.0], [0.5, 0.0, 0.0])
    watch.observe(2, apart, 4)
    assert watch.worst == pytest.approx(0.1 / 4) and watch.worst_frame == 1


def test_a_large_cloth_is_watched_through_a_fixed_sample_spread_over_it(monkeypatch):
    from warp_verlet.apps import contact_speed

    n = 140  # 19,600 colliding particles, over the limit
    scene = parse_scene(landing(substeps=2, cloths=[{**sheet("big", 0.6), "resolution": [n, n]}]), file="<t>")

    class Model:
        cloths = [type("Slot", (), {"first": 0})()]

    watch = ContactSpeedWatch(scene, Model())
    again = ContactSpeedWatch(scene, Model())
    assert len(watch.watched) == contact_speed.SAMPLE_LIMIT and np.array_equal(watch.watched, again.watched)
    assert np.all(np.diff(watch.watched) > 0) and watch.watched[-1] < n * n
    rows, cols = np.divmod(watch.watched, n)
    # every tenth of the rows and of the columns holds its share of the sample, give or take a fifth
    share = contact_speed.SAMPLE_LIMIT / 10
    for of in (rows, cols):
        assert np.all(np.abs(np.bincount(of * 10 // n, minlength=10) - share) < 0.2 * share)


def test_a_sampled_watch_still_sees_the_landing(monkeypatch, tmp_path):
    from warp_verlet.apps import contact_speed

    monkeypatch.setattr(contact_speed, "SAMPLE_LIMIT", 60)  # 60 of the two sheets' 288 particles
    assert summary_of(landing(substeps=2), tmp_path).contact_speed is not None


def test_the_thicker_contact_it_names_holds_the_same_landing(tmp_path):
    text = summary_of(landing(substeps=2), tmp_path).contact_speed
    strides = dict((name, int(k)) for k, name in re.findall(r"self_collision_stride = (\d+) on cloth '(\w+)'", text))
    assert set(strides) == {"bottom", "top"} and all(k > 1 for k in strides.values())
    cloths = [{**sheet(name, height), "self_collision_stride": strides[name]}
              for name, height in (("bottom", 0.03), ("top", 0.6))]
    assert summary_of(landing(substeps=2, cloths=cloths), tmp_path).contact_speed is None


def test_the_thicker_contact_for_a_given_thickness_and_where_no_stride_allows_one():
    from warp_verlet.apps.contact_speed import thicker_contact

    def spec_of(**cloth):
        return parse_scene(landing(substeps=2, cloths=[{**sheet("c", 0.6), **cloth}]), file="<t>").cloths[0]

    given = spec_of(collision_thickness=0.02)
    # Within the collision spacing (45 mm): the thickness alone.
    assert thicker_contact(given, 0.02, 0.04) == "collision_thickness = 0.04 on cloth 'c' (m; at most 0.0455 at its stride)"
    # Past it: the stride that makes room for it.
    assert thicker_contact(given, 0.02, 0.06) == "self_collision_stride = 2 and collision_thickness = 0.06 on cloth 'c' (m)"
    # A default thickness grows with the stride, up to the grid's 11 spacings.
    default = spec_of()
    assert thicker_contact(default, THICKNESS, 3 * THICKNESS).startswith("self_collision_stride = 3 on cloth 'c'")
    assert thicker_contact(default, THICKNESS, 12 * THICKNESS) is None


def test_a_mesh_cloths_advice_is_its_stride_over_its_median_edge(tmp_path):
    from test_angle_limit import strip_obj

    strip_obj(tmp_path / "strip.obj", rows=12, cols=12)  # 12 x 12 vertices, 0.05 m apart: default thickness 40 mm
    scene = parse_scene({"simulation": {"substeps": 2}, "cloth": [{"mesh": "strip.obj", "self_collision": True}]},
                        str(tmp_path / "s.toml"), tmp_path / "s.toml")

    class Model:
        cloths = [type("Slot", (), {"first": 0})()]

    watch = ContactSpeedWatch(scene, Model())
    start = scene.cloths[0].mesh.mesh.particle_points.astype(np.float64)
    watch.observe(0, start, 2)
    moved = start.copy()
    moved[0, 1] -= 0.1  # one particle 50 mm a substep against its neighbours: 1.25 thicknesses
    watch.observe(1, moved, 2)
    text = watch.advice()
    assert "substeps = 5 or more" in text  # 2 x 50 / 20 mm
    assert "self_collision_stride = 3 on cloth" in text  # 100 mm needed, 40 mm a stride
