"""USD point caches: one time-sampled ``points`` attribute per cloth, saved every few frames.

Layout of a cache::

    /World                 Xform, the stage's defaultPrim
    /World/<cloth>         Mesh (faces of any size, UVs in primvars:st) or, for a rope, linear BasisCurves
    /World/Colliders/<n>   each collider as its kind defines it (warp_verlet/colliders): a Sphere (time-sampled
                           translate when it moves), a large quad Mesh for a plane, a Mesh of triangles for a
                           mesh collider, or for one read from a USD prim an Xform placing a reference to it

``points`` and ``extent`` are time-sampled every frame; a time code is a frame number
(timeCodesPerSecond == framesPerSecond == fps). A mesh keeps the faces and UVs it was given (triangles,
quads, n-gons; UVs per vertex or per face corner). A cloth that can tear shows its torn faces (those beside
a torn stick) one of two ways, sampled only on frames where the torn set changes, since USD holds an
array's value until its next sample:

- ``torn_faces="remove"``: time-sampled ``faceVertexCounts`` and ``faceVertexIndices`` (and face-corner UVs)
  without the torn faces. Every DCC shows it, Blender included, which ignores holeIndices;
- ``torn_faces="holes"``: time-sampled ``holeIndices``; the face indices stay those of the source, which an
  asset's GeomSubsets and material bindings rely on. usdview, Houdini and Karma hide those faces.

Nothing else is authored: no normals (renderers compute smooth ones), no velocities (they double the file
size), and nothing about tearing on a cloth that cannot tear. Colliders carry a USD ``purpose``: "guide"
(hidden in renders, shown by usdview's guide toggle) or "default".

An *override layer* (``override_asset``) instead authors only ``points`` and ``extent`` (and the torn faces)
as ``over``s at each cloth's own prim path in that asset, which it sublayers: opening the layer plays the
simulation on the asset with its materials and hierarchy. It has no colliders and takes the asset's upAxis,
metersPerUnit and defaultPrim.

``USD_POINT_CACHE`` is the format writer_registry.py opens for the suffixes .usd, .usda and .usdc.

This module and ``preview.py`` import ``pxr``; neither imports warp: writing, checking and previewing a cache
must not pull in the simulator.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Callable, Sequence

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom, UsdValidation, Vt

from ..colliders.plane import CachedPlane, plane_corners  # noqa: F401 (each kind's cache record, here as before)
from ..colliders.sphere import CachedSphere  # noqa: F401
from ..errors import ArgumentError, OutputError, StateError, usd_cause, usd_diagnostics
from ..geometry.faces import Faces, as_faces
from .output_file import estimate_cache
from ..writer_registry import USD_SUFFIXES, CacheRequest

WORLD_PATH = Sdf.Path("/World")
# A rope is drawn as a tube 5 mm across, expressed in stage units so it looks the same at any scale.
ROPE_WIDTH_METRES = 0.005


@dataclass(frozen=True)
class CachedShape:
    """The static part of one cloth in the cache.

    ``faces`` may also be given as an (F, k) array of vertex indices (a grid's (F, 4) quads), a convenience
    for callers that still hold one; it is converted with ``Faces.uniform``, so ``faces`` is always Faces.
    """

    name: str  # USD prim name (already a valid identifier)
    faces: Faces  # triangles, quads, n-gons, or a mix; no faces means a rope/strand
    uvs: np.ndarray | None  # float32 (N, 2) per vertex or (corners, 2) per face corner; None: no UVs
    point_count: int
    tears: bool = False  # can faces be hidden by tearing?
    uv_interpolation: str = "vertex"  # "vertex" or "faceVarying"
    left_handed: bool = False  # faces wind clockwise seen from the front (USD orientation "leftHanded")
    prim_path: str | None = None  # an override layer's target prim in the asset

    def __post_init__(self) -> None:
        object.__setattr__(self, "faces", as_faces(self.faces))

    @property
    def is_rope(self) -> bool:
        return len(self.faces) == 0


COLLIDERS_PATH = WORLD_PATH.AppendChild("Colliders")


def _check_shapes(shapes: Sequence[CachedShape]) -> None:
    if not shapes:
        raise ArgumentError("a point cache needs at least one shape")
    names = [s.name for s in shapes]
    if len(set(names)) != len(names):
        raise ArgumentError(f"shape names must be unique, got {names}")
    for s in shapes:
        if not Sdf.Path.IsValidIdentifier(s.name):
            raise ArgumentError(f"shape name {s.name!r} is not a valid USD prim name")
        if s.is_rope:
            if s.point_count < 2:  # a linear curve needs two vertices
                raise ArgumentError(f"rope {s.name!r} needs at least 2 points, got {s.point_count}")
            continue
        s.faces.validate(s.point_count, f"shape {s.name!r}")
        if s.uvs is None:
            continue
        rows = {"vertex": s.point_count, "faceVarying": len(s.faces.indices)}.get(s.uv_interpolation)
        if rows is None:
            raise ArgumentError(f"shape {s.name!r}: uv_interpolation must be 'vertex' or 'faceVarying', "
                             f"got {s.uv_interpolation!r}")
        if np.shape(s.uvs) != (rows, 2):
            raise ArgumentError(f"shape {s.name!r}: {s.uv_interpolation} uvs must be ({rows}, 2), got {np.shape(s.uvs)}")


def _create_stage(path: Path) -> Usd.Stage:
    if path.suffix not in USD_SUFFIXES:
        raise OutputError(f"cannot write USD cache {path}: the file name must end in {', '.join(USD_SUFFIXES)}")
    # USD's resolver silently creates missing parent directories; a typo in --output should fail instead.
    parent = path.parent
    if not parent.is_dir():
        raise OutputError(f"cannot write USD cache {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputError(f"cannot write USD cache {path}: directory {parent} is not writable")
    # CreateNew refuses an identifier that a live layer in this process already has (a stage still open
    # on an earlier cache); say so plainly rather than surfacing Sdf's message.
    if Sdf.Layer.Find(str(path)):
        raise OutputError(f"cannot write USD cache {path}: the file is open in this process; release it first")
    try:
        return Usd.Stage.CreateNew(str(path))  # truncates an existing file
    except Tf.ErrorException as e:
        raise OutputError(f"cannot write USD cache {path}: {usd_cause(e)}") from e


class PointCacheWriter:
    """Writes one frame at a time and saves every ``save_every`` frames.

    A layer keeps every unsaved time sample in memory, so periodic saves keep memory flat, and they make
    the file on disk a valid cache of the frames saved so far (endTimeCode is updated before each save).
    If the process dies, at most ``save_every - 1`` frames are lost. Use it as a context manager, so that
    an exception still saves the frames written before it.

    ``before_save(writer)``, when given, is called before every save and may raise to prevent it (the run's
    free-space check, output_file.py); after such a refusal the writer saves nothing more, so that ``close``
    leaves the file as the last successful save wrote it. ``saved_frames`` / ``saved_frame`` say what is on
    disk: how many frames, and the last one (None before the first).
    """

    def __init__(self, path: str | os.PathLike[str], shapes: Sequence[CachedShape], fps: float, *,
                 up_axis: str = "Y", meters_per_unit: float = 1.0, save_every: int = 10, start_frame: int = 0,
                 metadata: dict[str, str] | None = None, colliders: Sequence = (),
                 torn_faces: str = "holes", override_asset: str | os.PathLike[str] | None = None,
                 before_save: Callable[[PointCacheWriter], None] | None = None):
        _check_shapes(shapes)
        if colliders and any(s.name == COLLIDERS_PATH.name for s in shapes):
            raise ArgumentError(f"shape name {COLLIDERS_PATH.name!r} is where the colliders go; rename the shape")
        if torn_faces not in ("holes", "remove"):
            raise ArgumentError(f"torn_faces must be 'holes' or 'remove', got {torn_faces!r}")
        if override_asset is not None and colliders:
            raise ArgumentError("an override layer has no colliders: they stand in for the asset's own geometry")
        if not (np.isfinite(fps) and fps > 0):
            raise ArgumentError(f"fps must be a positive number, got {fps}")
        if up_axis not in ("Y", "Z"):
            raise ArgumentError(f"up_axis must be 'Y' or 'Z', got {up_axis!r}")
        if not (np.isfinite(meters_per_unit) and meters_per_unit > 0):
            raise ArgumentError(f"meters_per_unit must be a positive number, got {meters_per_unit}")
        if save_every < 1:
            raise ArgumentError(f"save_every must be at least 1, got {save_every}")

        self.path = Path(path).absolute()
        self.shapes = tuple(shapes)
        self.save_every = int(save_every)
        self.start_frame = int(start_frame)
        self.frames_written = 0
        self.saved_frames = 0  # frames on disk
        self.saved_frame: int | None = None  # the last frame on disk
        self._before_save = before_save
        self._refused = False  # a before_save refused a save: write nothing more to disk
        self._last_frame: int | None = None
        self.torn_faces = torn_faces
        self._holes: dict[int, np.ndarray] = {}  # per tearing shape: the hidden faces last authored
        self._stage: Usd.Stage | None = _create_stage(self.path)

        stage = self._stage
        stage.SetStartTimeCode(self.start_frame)
        stage.SetEndTimeCode(self.start_frame)
        # Both rates, so that a time code is a frame whichever one a reader consults.
        stage.SetTimeCodesPerSecond(fps)
        stage.SetFramesPerSecond(fps)
        if metadata:
            stage.GetRootLayer().customLayerData = {str(k): str(v) for k, v in metadata.items()}
        if override_asset is not None:
            self._prims: list[UsdGeom.PointBased] = self._bind_overrides(stage, Path(override_asset))
            meters_per_unit = UsdGeom.GetStageMetersPerUnit(stage)
        else:
            UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
            UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
            stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, WORLD_PATH).GetPrim())
        rope_width = ROPE_WIDTH_METRES / meters_per_unit
        if override_asset is None:
            self._prims = [self._define_rope(stage, WORLD_PATH.AppendChild(shape.name), shape, rope_width)
                           if shape.is_rope else self._define_mesh(stage, WORLD_PATH.AppendChild(shape.name), shape)
                           for shape in self.shapes]
        self.colliders = tuple(colliders)
        self._moving: list[UsdGeom.XformOp] = []  # ops of moving colliders (a sphere's translate), in collider order
        if self.colliders:
            UsdGeom.Scope.Define(stage, COLLIDERS_PATH)
        for collider in self.colliders:  # each kind's record defines its own prim
            sampled = collider.define(stage, COLLIDERS_PATH.AppendChild(collider.name))
            if sampled is not None:
                self._moving.append(sampled)  # sampled per frame in write_frame
        # Curves pad their extent by half the width; keep the width array to compute it per frame.
        self._rope_widths = Vt.FloatArray([rope_width])
        try:
            self._save()  # the topology is on disk before the first frame, and write errors surface here
        except BaseException:
            # Release the layer, even while the caller holds this exception (and this frame): a later writer
            # may open the same path in this process.
            self._stage = stage = None
            self._prims, self._moving = [], []
            raise

    def _define_mesh(self, stage: Usd.Stage, prim_path: Sdf.Path, shape: CachedShape) -> UsdGeom.Mesh:
        mesh = UsdGeom.Mesh.Define(stage, prim_path)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(shape.faces.counts))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(shape.faces.indices))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # the fallback, catmullClark, would smooth it
        mesh.CreateDoubleSidedAttr(True)  # cloth is seen from both sides
        # Faces wind counter-clockwise (faces.py) unless the source said otherwise.
        mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded if shape.left_handed else UsdGeom.Tokens.rightHanded)
        if shape.uvs is not None:
            interpolation = UsdGeom.Tokens.faceVarying if shape.uv_interpolation == "faceVarying" else UsdGeom.Tokens.vertex
            st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interpolation)
            st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(shape.uvs, dtype=np.float32)))
        return mesh

    def _bind_overrides(self, stage: Usd.Stage, asset: Path) -> list[UsdGeom.PointBased]:
        """Sublayer ``asset`` and find each shape's prim in it, whose points the frames override."""
        if not asset.is_file():
            raise OutputError(f"cannot write override layer {self.path}: asset {asset} does not exist")
        try:
            relative = os.path.relpath(asset.absolute(), self.path.parent)
        except ValueError:  # another drive (Windows): only an absolute path reaches it
            relative = str(asset.absolute())
        layer = stage.GetRootLayer()
        layer.subLayerPaths.append(Path(relative).as_posix())
        source = Usd.Stage.Open(str(asset))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(source))
        UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.GetStageMetersPerUnit(source))
        if source.GetRootLayer().defaultPrim:
            layer.defaultPrim = source.GetRootLayer().defaultPrim
        prims = []
        for shape in self.shapes:
            prim = stage.GetPrimAtPath(shape.prim_path or "/")
            if not prim.IsValid() or not prim.IsA(UsdGeom.Mesh):
                raise OutputError(f"cannot write override layer {self.path}: {asset} has no Mesh at {shape.prim_path}")
            mesh = UsdGeom.Mesh(prim)
            known = mesh.GetPointsAttr().Get(Usd.TimeCode.EarliestTime())
            if known is None or len(known) != shape.point_count:
                raise OutputError(f"cannot write override layer {self.path}: {shape.prim_path} in {asset} has "
                                  f"{0 if known is None else len(known)} points, the cloth {shape.point_count}")
            prims.append(mesh)
        return prims

    @staticmethod
    def _define_rope(stage: Usd.Stage, prim_path: Sdf.Path, shape: CachedShape,
                     width: float) -> UsdGeom.BasisCurves:
        curves = UsdGeom.BasisCurves.Define(stage, prim_path)
        curves.CreateTypeAttr(UsdGeom.Tokens.linear)  # the particles are the polyline; no spline through them
        curves.CreateWrapAttr(UsdGeom.Tokens.nonperiodic)
        curves.CreateCurveVertexCountsAttr(Vt.IntArray([shape.point_count]))
        curves.CreateWidthsAttr(Vt.FloatArray([width]))
        curves.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        return curves

    def write_frame(self, frame: int, points: Sequence[np.ndarray], moving_centres: np.ndarray | None = None,
                    hidden_faces: Sequence[np.ndarray | None] | None = None) -> None:
        """Author ``points`` and ``extent`` of every shape at time code ``frame``, the translate of every
        moving sphere (``moving_centres``: one row per moving sphere, in collider order) and, for shapes that
        tear, ``hidden_faces`` (one array of face indices per shape, or None where unchanged or not tearing;
        holeIndices is sampled only when the set differs from the last one written)."""
        if self._stage is None:
            raise StateError(f"the point cache {self.path} is closed")
        if frame < self.start_frame:
            raise ArgumentError(f"frame {frame} is before the start frame {self.start_frame}")
        if self._last_frame is not None and frame <= self._last_frame:
            raise ArgumentError(f"frames must increase: got frame {frame} after frame {self._last_frame}")
        if len(points) != len(self.shapes):
            raise ArgumentError(f"expected {len(self.shapes)} point arrays, one per shape, got {len(points)}")
        # Check every array before authoring any, so that a bad call leaves no half-written frame.
        arrays = []
        for shape, p in zip(self.shapes, points):
            a = np.ascontiguousarray(p, dtype=np.float32)  # no copy when it already is float32 C-order
            if a.shape != (shape.point_count, 3):
                raise ArgumentError(f"shape {shape.name!r}: points must be ({shape.point_count}, 3), got {a.shape}")
            arrays.append(a)
        centres = np.zeros((0, 3)) if moving_centres is None else np.asarray(moving_centres, np.float64)
        if centres.shape != (len(self._moving), 3):
            raise ArgumentError(f"expected ({len(self._moving)}, 3) moving sphere centres, got {centres.shape}")
        holes = self._changed_holes(hidden_faces)

        time = Usd.TimeCode(frame)
        for op, centre in zip(self._moving, centres):
            op.Set(tuple(float(c) for c in centre), time)
        for shape, prim, a in zip(self.shapes, self._prims, arrays):
            vt_points = Vt.Vec3fArray.FromNumpy(a)
            if shape.is_rope:
                extent = UsdGeom.Curves.ComputeExtent(vt_points, self._rope_widths)
            else:
                extent = UsdGeom.PointBased.ComputeExtent(vt_points)
            prim.GetPointsAttr().Set(vt_points, time)
            prim.GetExtentAttr().Set(extent, time)
        for k, faces in holes.items():
            self._author_torn(k, faces, time)
            self._holes[k] = faces
        self._last_frame = int(frame)
        self.frames_written += 1
        if self.frames_written % self.save_every == 0:
            self._save()

    def _changed_holes(self, hidden_faces: Sequence[np.ndarray | None] | None) -> dict[int, np.ndarray]:
        """Checked hidden-face sets to author this frame, by shape index: every tearing shape on the first
        frame (an empty set until something tears), afterwards only the sets that changed."""
        given = [None] * len(self.shapes) if hidden_faces is None else list(hidden_faces)
        if len(given) != len(self.shapes):
            raise ArgumentError(f"expected {len(self.shapes)} hidden-face arrays (or None), one per shape, got {len(given)}")
        out = {}
        for k, (shape, faces) in enumerate(zip(self.shapes, given)):
            if not shape.tears or shape.is_rope:
                if faces is not None and len(faces):
                    raise ArgumentError(f"shape {shape.name!r} does not tear, so it has no faces to hide")
                continue
            if faces is None:
                if k in self._holes:
                    continue  # unchanged
                faces = np.zeros(0, np.int32)
            faces = np.unique(np.asarray(faces, dtype=np.int32))
            if len(faces) and (faces[0] < 0 or faces[-1] >= len(shape.faces)):
                raise ArgumentError(f"shape {shape.name!r}: hidden face indices must lie in [0, {len(shape.faces)})")
            if k not in self._holes or not np.array_equal(faces, self._holes[k]):
                out[k] = faces
        return out

    def _author_torn(self, k: int, hidden: np.ndarray, time: Usd.TimeCode) -> None:
        """Show shape k with the faces ``hidden`` from ``time`` on: as holeIndices, or as a topology without them."""
        prim, shape = self._prims[k], self.shapes[k]
        if self.torn_faces == "holes":
            prim.GetHoleIndicesAttr().Set(Vt.IntArray.FromNumpy(hidden), time)
            return
        keep = np.ones(len(shape.faces), bool)
        keep[hidden] = False
        corners = np.repeat(keep, shape.faces.counts)
        prim.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(shape.faces.counts[keep]), time)
        prim.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(shape.faces.indices[corners]), time)
        if shape.uvs is not None and shape.uv_interpolation == "faceVarying":  # one UV per face corner
            st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
            if st.IsIndexed():  # an asset's indexed UVs: author them flattened, per kept corner
                st.BlockIndices()
            uvs = np.ascontiguousarray(shape.uvs[corners], dtype=np.float32)
            st.Set(Vt.Vec2fArray.FromNumpy(uvs), time)

    def _save(self) -> None:
        assert self._stage is not None
        if self._refused:
            return
        if self._before_save is not None:
            try:
                self._before_save(self)
            except BaseException:
                self._refused = True
                raise
        # The range must cover only what is on disk, so it is moved just before each save.
        end = self._last_frame if self._last_frame is not None else self.start_frame
        self._stage.SetEndTimeCode(end)
        try:
            saved = self._stage.GetRootLayer().Save()
        except Tf.ErrorException as e:
            raise OutputError(f"cannot save USD cache {self.path}: {usd_cause(e)}") from e
        if not saved:
            raise OutputError(f"cannot save USD cache {self.path}")
        self.saved_frames, self.saved_frame = self.frames_written, self._last_frame

    def close(self) -> None:
        """Save the frames not yet saved and release the stage. Calling it again does nothing."""
        if self._stage is None:
            return
        try:
            self._save()
        finally:
            self._stage = None  # drop the layer, so the file can be reopened or rewritten in this process
            self._prims, self._moving = [], []

    def __enter__(self) -> PointCacheWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            self.close()
        except OutputError:
            if exc is None:
                raise
            # The error in flight says why the run stopped; what is on disk is in saved_frames / saved_frame.


def validate_cache(path: str | os.PathLike[str]) -> list[str]:
    """Check a point cache; return human-readable problems, empty when the cache is valid."""
    path = Path(path)
    if not path.is_file():
        return [f"{path}: no such file"]
    try:
        with usd_diagnostics() as warnings:  # USD's own text carries its C++ file and line: say it plainly
            stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as e:
        return [f"{path}: cannot be opened as USD: {usd_cause(e)}"]
    if warnings:  # a cache that warns as it opens (a missing or broken layer) does not play as written
        return [f"{path}: {warning}" for warning in warnings]

    # USD's own validators: stage metadata, composition, attribute types. Warnings are advice; keep errors.
    context = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    problems = [err.GetErrorAsString() for err in context.Validate(stage)
                if err.GetType() == UsdValidation.ValidationErrorType.Error]
    problems += _check_stage_metadata(stage)
    # Time samples outside [start, end] mean endTimeCode was not kept up to date.
    time_range = (stage.GetStartTimeCode(), stage.GetEndTimeCode())
    for prim in stage.Traverse():
        if _referenced_collider(prim):
            continue  # the asset's own prim (colliders/mesh.ReferencedMesh): its geometry and samples are the asset's
        if prim.IsA(UsdGeom.Mesh):
            problems += _check_mesh(UsdGeom.Mesh(prim), time_range)
        elif prim.IsA(UsdGeom.BasisCurves):
            curves = UsdGeom.BasisCurves(prim)
            counts = curves.GetCurveVertexCountsAttr().Get()
            problems += _check_points(curves, int(np.sum(counts)) if counts else 0, time_range)
    return problems


def _referenced_collider(prim: Usd.Prim) -> bool:
    """A collider prim under /World/Colliders that references its source asset (or lies below one)."""
    while prim and prim.GetPath().HasPrefix(COLLIDERS_PATH):
        if prim.HasAuthoredReferences():
            return True
        prim = prim.GetParent()
    return False


def _check_stage_metadata(stage: Usd.Stage) -> list[str]:
    layer = stage.GetRootLayer()
    problems = []
    if not (layer.HasTimeCodesPerSecond() and layer.HasFramesPerSecond()):
        problems.append("stage: timeCodesPerSecond and framesPerSecond must both be authored")
    elif layer.timeCodesPerSecond != layer.framesPerSecond:
        problems.append(f"stage: timeCodesPerSecond {layer.timeCodesPerSecond} != "
                        f"framesPerSecond {layer.framesPerSecond}, so time codes are not frames")
    if not (layer.HasStartTimeCode() and layer.HasEndTimeCode()):
        problems.append("stage: startTimeCode and endTimeCode must both be authored")
    for key in ("upAxis", "metersPerUnit"):
        if not stage.HasAuthoredMetadata(key):
            problems.append(f"stage: {key} is not authored")
    if not stage.GetDefaultPrim():
        problems.append("stage: defaultPrim is missing or names no prim")
    return problems


def _check_mesh(mesh: UsdGeom.Mesh, time_range: tuple[float, float]) -> list[str]:
    name = mesh.GetPath()
    problems = []
    points_attr = mesh.GetPointsAttr()
    times = points_attr.GetTimeSamples()
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    has_st = bool(st) and st.HasAuthoredValue()
    vertex_st = has_st and st.GetInterpolation() in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying)
    st_values = st.ComputeFlattened() if has_st else None
    # The point count is the first sample's (_check_points checks that every other sample agrees); a
    # cache with no frame yet has only its per-vertex UVs to say how many points there will be.
    first = points_attr.Get(times[0]) if times else points_attr.Get()
    n_points = len(first) if first is not None else (len(st_values) if vertex_st and st_values is not None else None)
    if n_points is None:
        return [f"{name}: has neither points nor per-vertex primvars:st, so its point count is unknown"]

    # Torn faces may be left out of a time-sampled topology: check it at the default time and every sample.
    counts_attr, indices_attr = mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr()
    topology_times = sorted(set(counts_attr.GetTimeSamples()) | set(indices_attr.GetTimeSamples()))
    for time in [Usd.TimeCode.Default()] + [Usd.TimeCode(t) for t in topology_times]:
        when = "" if time.IsDefault() else f" at time {time.GetValue()}"
        indices = indices_attr.Get(time) or Vt.IntArray()
        counts = counts_attr.Get(time) or Vt.IntArray()
        ok, reason = UsdGeom.Mesh.ValidateTopology(indices, counts, n_points)
        if not ok:
            problems.append(f"{name}: invalid topology{when}: {reason}")
            continue
        try:  # USD accepts faces of 0, 1 or 2 corners, which no renderer draws; Faces.validate does not
            Faces(np.asarray(counts), np.asarray(indices)).validate(n_points, f"{name}{when}")
        except ValueError as e:
            problems.append(str(e))
        if has_st:
            values = st.ComputeFlattened(time)
            expected = n_points if vertex_st else len(indices)
            if values is not None and len(values) != expected:
                what = "points" if vertex_st else "face corners"
                problems.append(f"{name}: primvars:st has {len(values)} values for {expected} {what}{when}")
        holes = mesh.GetHoleIndicesAttr()
        for t in holes.GetTimeSamples() if time.IsDefault() else ():
            hidden = np.asarray(holes.Get(t), dtype=np.int64)
            n_faces = len(counts_attr.Get(Usd.TimeCode(t)) or counts)
            if len(hidden) and (hidden.min() < 0 or hidden.max() >= n_faces):
                problems.append(f"{name}: holeIndices at time {t} names a face outside [0, {n_faces})")
    if mesh.GetSubdivisionSchemeAttr().Get() != UsdGeom.Tokens.none:
        problems.append(f"{name}: subdivisionScheme is not 'none', so renderers would smooth the cloth")
    return problems + _check_points(mesh, n_points, time_range)


def _check_points(prim: UsdGeom.PointBased, n_points: int, time_range: tuple[float, float]) -> list[str]:
    name = prim.GetPath()
    problems = []
    points_attr, extent_attr = prim.GetPointsAttr(), prim.GetExtentAttr()
    extent_times = set(extent_attr.GetTimeSamples())
    for t in points_attr.GetTimeSamples():
        if not time_range[0] <= t <= time_range[1]:
            problems.append(f"{name}: points sample at time {t} lies outside the stage's time range {time_range}")
        pts = np.asarray(points_attr.Get(t))
        if len(pts) != n_points:
            problems.append(f"{name}: points at time {t} has {len(pts)} points, expected {n_points}")
            continue
        if not np.isfinite(pts).all():
            problems.append(f"{name}: points at time {t} contains non-finite values")
            continue
        if t not in extent_times:
            problems.append(f"{name}: no extent sample at time {t}")
            continue
        lo, hi = np.asarray(extent_attr.Get(t), dtype=np.float64)
        # Our extents are computed from the same float32 points, so they hold exactly; the small slack
        # only forgives other writers that rounded a float64 extent to float32.
        tol = 1e-6 * max(1.0, float(np.abs([lo, hi]).max()))
        if len(pts) and ((pts < lo - tol).any() or (pts > hi + tol).any()):
            problems.append(f"{name}: extent at time {t} does not contain all points")
    return problems


def complete_cache_problems(path: str | os.PathLike[str], frames: int) -> list[str]:
    """Why the cache at ``path`` is not a complete cache of ``frames`` frames (empty when it is): it must open,
    pass ``validate_cache``, span time codes 0 .. frames, and hold points at every one of them."""
    problems = validate_cache(path)
    if problems:
        return problems
    with usd_diagnostics():  # validate_cache said what matters of them
        stage = Usd.Stage.Open(str(path))
    if (stage.GetStartTimeCode(), stage.GetEndTimeCode()) != (0, frames):
        return [f"{path}: frames {stage.GetStartTimeCode():g} .. {stage.GetEndTimeCode():g}, expected 0 .. {frames}"]
    shapes = [p for p in stage.Traverse() if p.IsA(UsdGeom.PointBased) and UsdGeom.PointBased(p).GetPointsAttr().GetNumTimeSamples()
              and not _referenced_collider(p)]
    if not shapes:
        return [f"{path}: no animated points"]
    for prim in shapes:
        n = UsdGeom.PointBased(prim).GetPointsAttr().GetNumTimeSamples()
        if n != frames + 1:
            return [f"{path}: {prim.GetPath()} has {n} frames of points, expected {frames + 1}"]
    return []


class UsdPointCache:
    """The USD point cache format (writer_registry.CacheFormat): a PointCacheWriter, or with the request's
    ``override_asset`` an override layer over that asset (a mode of the same writer: see writer_registry)."""

    name = "USD point cache"
    overrides = True

    def open(self, path: Path, request: CacheRequest) -> PointCacheWriter:
        return PointCacheWriter(
            path, request.shapes, fps=request.fps, up_axis=request.up_axis, meters_per_unit=request.meters_per_unit,
            save_every=request.save_every, start_frame=request.start_frame, metadata=request.metadata,
            colliders=request.colliders, torn_faces=request.torn_faces, before_save=request.before_save,
            override_asset=request.override_asset)

    def estimate(self, request: CacheRequest, path: Path):
        return estimate_cache(request.shapes, request.colliders, text=Path(path).suffix == ".usda")

    def problems(self, path: Path, frames: int) -> list[str]:
        return complete_cache_problems(path, frames)


USD_POINT_CACHE = UsdPointCache()
