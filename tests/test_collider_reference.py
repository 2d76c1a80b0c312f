"""A mesh collider read from a USD prim is cached as a USD reference to that prim (colliders/mesh.ReferencedMesh),
not as a copy of its points: the cache reads back to the triangles the simulation collided with, at every frame
of the asset's own animation, and passes the cache's checks."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from test_moving_mesh import CM, CROSSING, END_Z, START_Z, cube_points, scene_of, write_usd
from warp_verlet.apps.runner import run_scene
from warp_verlet.input.scene import parse_scene
from warp_verlet.output.cache_reader import open_cache, read_frame
from warp_verlet.output.usd_writer import validate_cache

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def triangle_set(points: np.ndarray, triangles: np.ndarray) -> set:
    """The triangles as sets of corners (m, rounded to 1e-5), whatever their winding and first corner."""
    return {frozenset(tuple(np.round(points[k], 5)) for k in t) for t in triangles}


def test_the_curtain_frames_cache_references_the_frame_and_reads_back_its_triangles(tmp_path):
    from pxr import Usd, UsdGeom

    data = tomllib.loads((SCENES / "curtain_frame.toml").read_text())
    data["output"] = {"path": "curtain.usda"}  # a standalone cache, which holds colliders (an override layer has none)
    data["simulation"]["frames"] = 2
    scene = parse_scene(data, file=str(SCENES / "curtain_frame.toml"), scene_path=SCENES / "curtain_frame.toml")
    run_scene(scene, tmp_path / "curtain.usda", device="cpu")
    stage = Usd.Stage.Open(str(tmp_path / "curtain.usda"))
    frame = stage.GetPrimAtPath("/World/Colliders/frame/Frame")
    assert frame.IsA(UsdGeom.Mesh) and frame.HasAuthoredReferences()
    layer = stage.GetRootLayer()
    assert layer.GetPropertyAtPath("/World/Colliders/frame/Frame.points") is None  # not copied: referenced
    reference, = layer.GetPrimAtPath("/World/Colliders/frame/Frame").referenceList.prependedItems
    assert reference.primPath == "/Set/Window/Frame" and not Path(reference.assetPath).is_absolute()
    assert (tmp_path / reference.assetPath).resolve() == (SCENES / "assets" / "curtain.usda").resolve()
    assert validate_cache(tmp_path / "curtain.usda") == []
    spec = scene.colliders[0]
    cache = open_cache(tmp_path / "curtain.usda")
    for number in (0, 2):
        (points, triangles), = read_frame(cache, number).meshes
        assert triangle_set(points, triangles) == triangle_set(spec.points, spec.triangles)


def test_an_animated_usd_collider_plays_its_own_animation_from_the_cache(tmp_path):
    # A translated rig and a deforming cube (24 time codes a second in the asset, 60 frames a second in the
    # cache), scaled and placed by the scene: the cache reads back where the simulation put them at every frame.
    codes = {0.0: START_Z, CROSSING * 24.0: END_Z}
    write_usd(tmp_path / "rig.usda", translate_samples={c: (0.0, 0.0, z / CM) for c, z in codes.items()})
    cube = cube_points(10.0)[0]
    write_usd(tmp_path / "blob.usda", point_samples={c: cube * (1.0 + c / 10.0) + (0.0, 0.0, z / CM)
                                                     for c, z in codes.items()})
    scene = scene_of(tmp_path, [
        {"type": "mesh", "name": "rig", "mesh": "rig.usda", "prim": "/Rig/Box", "translate": [0.5, 0.0, 0.0]},
        {"type": "mesh", "name": "blob", "mesh": "blob.usda", "prim": "/Rig/Box", "scale": 0.5,
         "rotate": [[0.0, 0.0, 0.0, 0.0], [0.2, 0.0, 90.0, 0.0]], "translate": [[0.0, -1.0, 0.0, 0.0],
                                                                              [0.2, -1.0, 0.5, 0.0]]},
    ], frames=18)
    run_scene(scene, tmp_path / "out.usdc", device="cpu")
    assert validate_cache(tmp_path / "out.usdc") == []
    cache = open_cache(tmp_path / "out.usdc")
    for number in (0, 5, 10, 18):
        drawn = read_frame(cache, number).meshes
        for spec, (points, triangles) in zip(scene.colliders, drawn):
            placed = spec.points_at(number / 60)
            assert triangle_set(points, triangles) == triangle_set(placed, spec.triangles), (spec.name, number)


def test_a_spinning_usd_prim_on_a_moving_parent_is_placed_as_usd_places_it(tmp_path):
    # The prim turns a whole turn about its own Y in a second while its parent moves: USD interpolates the angle,
    # which the poses follow (halved until within POSE_TOLERANCE), and the cache plays it through the reference.
    from pxr import Usd, UsdGeom

    write_usd(tmp_path / "spin.usda", translate_samples={0.0: (0.0, 0.0, 0.0), 24.0: (50.0, 0.0, 0.0)},
              spin_samples={0.0: 0.0, 24.0: 360.0})
    scene = scene_of(tmp_path, [{"type": "mesh", "name": "spin", "mesh": "spin.usda", "prim": "/Rig/Box",
                                 "translate": [0.0, -1.0, 0.0]}], frames=60)
    spec = scene.colliders[0]
    assert len(spec.poses) >= 5  # one turn between two samples: halved into quarter turns or less
    asset = Usd.Stage.Open(str(tmp_path / "spin.usda"))
    box = UsdGeom.Mesh(asset.GetPrimAtPath("/Rig/Box"))
    local = np.asarray(box.GetPointsAttr().Get(), np.float64)
    run_scene(scene, tmp_path / "out.usdc", device="cpu")
    cache = open_cache(tmp_path / "out.usdc")
    for seconds in (0.1, 0.25, 0.5, 0.8, 1.0):
        matrix = np.asarray(box.ComputeLocalToWorldTransform(Usd.TimeCode(seconds * 24.0)), np.float64)
        expected = (local @ matrix[:3, :3] + matrix[3, :3]) * CM + (0.0, -1.0, 0.0)
        simulated = spec.points_at(seconds)
        nearest = np.linalg.norm(expected[:, None] - simulated[None], axis=2).min(axis=1)
        assert nearest.max() < 2e-5, seconds
        (points, _), = read_frame(cache, round(seconds * 60)).meshes
        assert np.abs(points - expected).max() < 2e-5, seconds  # the reference's own points, in the asset's order
