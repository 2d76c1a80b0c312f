"""Collider kinds describe themselves (warp_verlet/colliders): every registered kind implements the protocol
and documents its keys, the registry is the clamp order, and a kind written here, in the test, with its own
kernel, is read from TOML, clamps particles, is counted by the memory estimate and is launched, without any
library file knowing it."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import warp as wp

from bench.common import device_arrays
from warp_verlet import colliders
from warp_verlet.colliders import (SHARED_KEYS, ColliderKind, ColliderLaunches, InsideReport, kind_named)
from warp_verlet.colliders.plane import PLANE, PlaneCollider
from warp_verlet.colliders.sphere import SPHERE, SphereCollider
from warp_verlet.errors import SceneError
from warp_verlet.core.memory import estimate
from warp_verlet.input.scene import parse_scene
from warp_verlet.scene_keys import Key, choice, real
from warp_verlet.input.scene_warnings import start_inside_warnings
from warp_verlet.core.simulator import Simulator

# Every member the protocol declares: its methods and its annotated attributes.
PROTOCOL_METHODS = sorted(n for n, v in vars(ColliderKind).items() if callable(v) and not n.startswith("_"))
PROTOCOL_ATTRIBUTES = sorted(ColliderKind.__annotations__)


def test_the_protocol_declares_the_members_the_consumers_use():
    assert PROTOCOL_ATTRIBUTES == ["keys", "spec", "type"]
    assert {"read", "check_numbers", "start_inside", "counts", "device_bytes", "build", "state_arrays",
            "bind"} <= set(PROTOCOL_METHODS)


@pytest.mark.parametrize("kind", colliders.COLLIDER_KINDS, ids=lambda k: k.type)
def test_every_registered_kind_implements_the_protocol(kind):
    assert isinstance(kind, ColliderKind)
    for name in PROTOCOL_METHODS:
        assert callable(getattr(kind, name, None)), f"{kind.type} has no method {name}"
    assert isinstance(kind.type, str) and kind.type
    assert isinstance(kind.spec, type)
    assert kind_named(kind.type) is kind
    for shared in ("name", "thickness", "friction_coefficient", "static_friction_coefficient", "purpose"):
        assert shared in kind.spec.__dataclass_fields__, f"{kind.type}'s spec lacks the shared key {shared}"


@pytest.mark.parametrize("key", [*SHARED_KEYS, *(k for kind in colliders.COLLIDER_KINDS for k in kind.keys)],
                         ids=lambda k: k.name)
def test_every_key_is_documented(key):
    assert isinstance(key, Key)
    assert key.type.strip() and key.unit.strip() and key.doc.strip() and key.allowed.strip()
    assert key.doc.rstrip().endswith("."), "the docs tables print the doc text as a sentence"


def test_the_docs_collider_tables_say_what_the_keys_declare():
    # docs/scenes.md's [[collider]] rows: | `key` | type | unit | default | allowed | meaning |
    text = (Path(__file__).resolve().parent.parent / "docs" / "scenes.md").read_text(encoding="utf-8")
    section = text[text.index("## `[[collider]]`"):]
    section = section[:section.index("\n## ", 1)]
    rows = {m[0]: m[1:] for m in re.findall(r"^\| `(\w+)` \| (.*?) \| (.*?) \| (.*?) \| (.*?) \| (.*) \|$", section,
                                            re.MULTILINE)}
    keys = [*SHARED_KEYS, *(k for kind in colliders.COLLIDER_KINDS for k in kind.keys)]
    assert sorted(rows) == sorted(k.name for k in keys)
    for key in keys:
        type_, unit, _, allowed, doc = rows[key.name]
        assert (type_, unit, allowed, doc) == (key.type, key.unit, key.allowed, key.doc), key.name


def test_kind_keys_are_distinct_from_the_shared_ones():
    shared = {k.name for k in SHARED_KEYS}
    for kind in colliders.COLLIDER_KINDS:
        names = [k.name for k in kind.keys]
        assert len(set(names)) == len(names) and not shared & set(names), kind.type


def test_the_registry_is_the_clamp_order():
    # Spheres and meshes before planes: the plane's clamp runs last, so that a sphere or a table standing on the
    # ground cannot push cloth through the ground.
    from warp_verlet.colliders.mesh import MESH

    assert [k.type for k in colliders.COLLIDER_KINDS] == ["sphere", "mesh", "plane"]
    assert colliders.COLLIDER_KINDS == (SPHERE, MESH, PLANE)


def test_the_scene_reads_each_collider_through_its_kind():
    scene = parse_scene({"cloth": [{"resolution": [2, 2], "size": [1.0, 1.0]}],
                         "collider": [{"type": "plane"}, {"type": "sphere", "radius": 0.5}]}, file="<test>")
    plane, sphere = scene.colliders
    assert isinstance(plane, PlaneCollider) and plane.name == "plane0" and plane.normal == (0.0, 1.0, 0.0)
    assert isinstance(sphere, SphereCollider) and sphere.name == "sphere1" and sphere.keyframes == ((0.0, (0, 0, 0)),)
    with pytest.raises(SceneError, match=r"<test>.*collider\[0\]\.type.*expected one of 'mesh', 'plane', 'sphere', got"):
        parse_scene({"cloth": [{"resolution": [2, 2], "size": [1.0, 1.0]}], "collider": [{"type": "cube"}]},
                    file="<test>")


# ------------------------------------------------------------------------------------------ a third kind
# A half-space given by an axis and a level (a parametrisation no library kind has): particles are kept at
# coordinate >= level + thickness along that axis. Float32 positions only, no friction: a test kind.


@wp.kernel
def keep_above_levels(x: wp.array(dtype=wp.vec3), inv_mass: wp.array(dtype=float), axes: wp.array(dtype=int),
                      floors: wp.array(dtype=float)):
    i = wp.tid()
    if inv_mass[i] == 0.0:
        return
    xi = x[i]
    for h in range(axes.shape[0]):
        a = axes[h]
        if xi[a] < floors[h]:
            xi[a] = floors[h]
    x[i] = xi


@dataclass(frozen=True)
class LevelCollider:
    name: str
    axis: int
    level: float
    thickness: float = 0.0
    friction_coefficient: float = 0.0
    static_friction_coefficient: float | None = None
    purpose: str = "guide"


AXIS = Key("axis", choice(("x", "y", "z")), "y", type="string", allowed='"x", "y", "z"', doc="The axis.")
LEVEL = Key("level", real(), type="number", unit="m", allowed="finite", doc="The lowest coordinate allowed.")


class LevelKind:
    type = "level"
    spec = LevelCollider
    keys = (AXIS, LEVEL)

    def read(self, table, shared: dict[str, Any]) -> LevelCollider:
        return LevelCollider(axis="xyz".index(AXIS.take(table)), level=LEVEL.take(table), **shared)

    def check_numbers(self, spec, file: str, key: str) -> None:
        if abs(spec.level) > 3.4e38:
            raise SceneError(file, f"{key}.level", "expected a number that float32 can hold")

    def start_inside(self, spec, points) -> InsideReport:
        return InsideReport(points[:, spec.axis] < spec.level + spec.thickness, f"below level '{spec.name}'",
                            "raise the cloth")

    def counts(self, specs) -> tuple[int]:
        return (len(specs),)

    def device_bytes(self, counts) -> int:
        return counts[0] * (4 + 4 + 4)  # axis, starting floor; the State's floor

    def build(self, specs, device) -> dict[str, Any]:
        return {"level_axes": wp.array([s.axis for s in specs], dtype=int),
                "level_start": wp.array([s.level + s.thickness for s in specs], dtype=float)}

    def state_arrays(self, colliders) -> dict[str, Any]:
        """The floors live in the State (as if a session could raise them), to exercise a kind's moving part."""
        start = getattr(colliders, "level_start", None)
        return {"level_floors": None if start is None else wp.clone(start)}

    def bind(self, model, state) -> ColliderLaunches:
        from warp_verlet.core.stages import recorded

        c = model.colliders
        return ColliderLaunches((), (recorded(keep_above_levels, model.particle_count,
                                              [state.particle_q, model.inv_mass, c.level_axes,
                                               state.level_floors]),))

    def samples(self, colliders, state, always_moving: bool = False):
        return np.zeros((0, 3), np.float32)

    def cached(self, spec, always_moving: bool = False) -> "CachedLevel":
        return CachedLevel(spec.name, spec.axis, spec.level, spec.purpose)

    def owns_prim(self, prim, under_colliders: bool) -> bool:
        return under_colliders and prim.HasAttribute("level:level")

    def read_prim(self, prim, reader) -> dict[str, Any]:
        from pxr import UsdGeom

        mesh = UsdGeom.Mesh(prim)
        points = reader.attribute(mesh, "points", lambda: mesh.GetPointsAttr().Get(reader.time))
        return {"planes": reader.to_world(mesh, reader.finite(mesh, points))}

    def add_to_live(self, app, specs):
        raise NotImplementedError("not drawn on the live page in these tests")


@dataclass(frozen=True)
class CachedLevel:
    name: str
    axis: int
    level: float
    purpose: str
    moving: bool = False

    def define(self, stage, path):
        """A 2 m square across the axis at the level, tagged with its level."""
        from pxr import Sdf, UsdGeom, Vt

        corners = np.zeros((4, 3), np.float32)
        u, v = [a for a in range(3) if a != self.axis]
        corners[:, self.axis] = self.level
        corners[:, u] = [-1, 1, 1, -1]
        corners[:, v] = [-1, -1, 1, 1]
        mesh = UsdGeom.Mesh.Define(stage, path)
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(corners))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
        mesh.CreatePurposeAttr(self.purpose)
        mesh.GetPrim().CreateAttribute("level:level", Sdf.ValueTypeNames.Float).Set(self.level)
        return None


LEVEL_KIND = LevelKind()
FALLING = {"simulation": {"fps": 60.0, "substeps": 4, "iterations": 2},
           "cloth": [{"resolution": [5, 5], "size": [1.0, 1.0], "orientation": "horizontal", "sticks": ["structural"]}]}


def falling_scene(*colliders_: dict):
    return parse_scene({**FALLING, "collider": list(colliders_)}, file="<test>")


@pytest.fixture
def with_level(monkeypatch):
    """The level kind registered after the library's kinds, for this test only."""
    monkeypatch.setattr(colliders, "COLLIDER_KINDS", (*colliders.COLLIDER_KINDS, LEVEL_KIND))
    return LEVEL_KIND


def test_a_kind_registered_in_a_test_is_read_from_toml(with_level):
    scene = falling_scene({"type": "level", "level": -0.25, "thickness": 0.01, "friction_coefficient": 0.2})
    (spec,) = scene.colliders
    assert spec == LevelCollider(name="level0", axis=1, level=-0.25, thickness=0.01, friction_coefficient=0.2)
    with pytest.raises(SceneError, match=r"<test>.*collider\[0\]\.axis.*expected one of 'x', 'y', 'z'"):
        falling_scene({"type": "level", "level": 0.0, "axis": "w"})
    with pytest.raises(SceneError, match=r"<test>.*collider\[0\]\.radius.*unknown key"):
        falling_scene({"type": "level", "level": 0.0, "radius": 1.0})
    with pytest.raises(SceneError, match=r"collider\[0\]\.level.*required"):
        falling_scene({"type": "level"})
    # Its own start-inside check reaches the scene's warnings.
    (warning,) = start_inside_warnings(falling_scene({"type": "level", "level": 1.0}))
    assert "starts with 25 of 25 particles below level 'level0'" in warning and "raise the cloth" in warning


def test_a_kind_registered_in_a_test_clamps_is_estimated_and_launched(with_level, launches):
    level = {"type": "level", "level": -0.25, "thickness": 0.01}
    ground = {"type": "plane", "point": [0.0, -1.0, 0.0]}
    sim = Simulator(falling_scene(level, ground), "cpu", use_graph=False)
    sim.step()
    # Its clamp runs in registry order, after the library kinds' clamps.
    assert launches.of(sim.step)[-2:] == ["collide_planes", "keep_above_levels"]
    assert [name for name, _ in sim.stages()] == ["integrate", "relax", "collide"]
    for _ in range(60):  # a second: a free fall takes the cloth 4.9 m down, far past the level
        sim.step_frame()
    heights = sim.positions()[:, 1]
    np.testing.assert_allclose(heights, -0.24, atol=1e-6)  # at rest on level + thickness, flat
    # The memory estimate counts its arrays: every device array the simulator holds, and no more.
    form = sim.model.sticks_form
    held = sum(a.capacity for a in device_arrays(sim).values())
    assert held == estimate(sim.scene, form).device_bytes
    without = estimate(falling_scene(ground), form).device_bytes
    assert estimate(sim.scene, form).device_bytes - without == LEVEL_KIND.device_bytes((1,)) == 12
    # Its moving part is the State's: listed, cloned and assigned with the rest.
    state = sim.state
    assert {a.ptr for a in vars(state).values() if isinstance(a, wp.array)} == {a.ptr for a in state.arrays().values()}
    twin = state.clone()
    assert twin.level_floors.ptr != state.level_floors.ptr
    np.testing.assert_array_equal(twin.level_floors.numpy(), np.float32([-0.24]))
    state.level_floors.assign(np.array([0.5], np.float32))
    state.assign(twin)
    np.testing.assert_array_equal(state.level_floors.numpy(), np.float32([-0.24]))
    # A scene without the kind still has the name, as None (the State's attributes do not depend on the scene).
    assert Simulator(falling_scene(ground), "cpu", use_graph=False).state.level_floors is None


def test_a_kind_without_clamp_pieces_still_clamps_on_cpu_threads(with_level):
    # The level kind makes its clamp over every particle only (no ``clamp_pieces``): on CPU threads the Collide
    # stage runs it whole, on the team's first thread, where the library's kinds clamp a run of particles each.
    level = {"type": "level", "level": -0.25, "thickness": 0.01}
    ground = {"type": "plane", "point": [0.0, -1.0, 0.0]}
    heights = []
    for threads in (1, 2):
        sim = Simulator(falling_scene(level, ground), "cpu", threads=threads)
        for _ in range(60):
            sim.step_frame()
        heights.append(sim.positions()[:, 1])
    np.testing.assert_allclose(heights[0], -0.24, atol=1e-6)
    np.testing.assert_array_equal(heights[1], heights[0])


def test_a_kind_registered_in_a_test_is_written_to_the_cache_and_read_back(monkeypatch, tmp_path):
    from pxr import Usd

    from warp_verlet.output.cache_reader import open_cache, read_frame
    from warp_verlet.apps.runner import run_scene

    # Before the plane: the cache reader asks the kinds in registry order, and the plane claims any mesh under
    # /World/Colliders.
    monkeypatch.setattr(colliders, "COLLIDER_KINDS", (SPHERE, LEVEL_KIND, PLANE))
    out = tmp_path / "level.usda"
    scene = falling_scene({"type": "level", "level": -0.25, "purpose": "default"},
                          {"type": "plane", "name": "ground", "point": [0.0, -1.0, 0.0], "display_size": 4.0})
    run_scene(scene, output=out, device="cpu", frames=2)
    stage = Usd.Stage.Open(str(out))
    prim = stage.GetPrimAtPath("/World/Colliders/level0")
    assert prim.GetAttribute("level:level").Get() == -0.25 and prim.GetAttribute("purpose").Get() == "default"
    cache = open_cache(out)
    assert [(kind.type, prim.GetName()) for kind, prim in cache.colliders] == [("level", "level0"), ("plane", "ground")]
    assert len(cache.cloths) == 1  # neither collider is taken for a cloth
    level_quad, ground_quad = read_frame(cache, 2).planes
    np.testing.assert_array_equal(level_quad[:, 1], -0.25)
    np.testing.assert_allclose(ground_quad[:, 1], -1.0, atol=1e-7)


def test_without_the_kind_registered_its_type_is_refused():
    with pytest.raises(SceneError, match=r"collider\[0\]\.type.*expected one of 'mesh', 'plane', 'sphere', got str 'level'"):
        falling_scene({"type": "level", "level": 0.0})
