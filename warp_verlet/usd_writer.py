"""USD point caches: one time-sampled ``points`` attribute per cloth, saved every few frames.

Layout of a cache::

    /World                 Xform, the stage's defaultPrim
    /World/<cloth>         Mesh (faces of any size, UVs in primvars:st) or, for a rope, linear BasisCurves
    /World/Colliders/<n>   Sphere (time-sampled translate when it moves) or a large quad Mesh for a plane

``points`` and ``extent`` are time-sampled every frame; a time code is a frame number
(timeCodesPerSecond == framesPerSecond == fps). A cloth that can tear also gets a time-sampled
``holeIndices`` (the faces beside a torn stick): empty on the first frame, then sampled only on frames where
the set changes, since USD holds an array's value until its next sample. Nothing else is authored: no
normals (renderers compute smooth ones), no velocities (they double the file size), and no holeIndices on a
cloth that cannot tear.

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

from .errors import ArgumentError, OutputError, StateError, usd_cause
from .faces import Faces, as_faces

WORLD_PATH = Sdf.Path("/World")
# A rope is drawn as a tube 5 mm across, expressed in stage units so it looks the same at any scale.
ROPE_WIDTH_METRES = 0.005
_EXTENSIONS = (".usd", ".usda", ".usdc")


@dataclass(frozen=True)
class CachedShape:
    """The static part of one cloth in the cache.

    ``faces`` may also be given as an (F, k) array of vertex indices (a grid's (F, 4) quads), a convenience
    for callers that still hold one; it is converted with ``Faces.uniform``, so ``faces`` is always Faces.
    """

    name: str  # USD prim name (already a valid identifier)
    faces: Faces  # triangles, quads, n-gons, or a mix; no faces means a rope/strand
    uvs: np.ndarray  # (N, 2) float32
    point_count: int
    tears: bool = False  # can faces be hidden by tearing (time-sampled holeIndices)?

    def __post_init__(self) -> None:
        object.__setattr__(self, "faces", as_faces(self.faces))

    @property
    def is_rope(self) -> bool:
        return len(self.faces) == 0


@dataclass(frozen=True)
class CachedSphere:
    """A sphere collider: its render-visible radius (thickness excluded) and where it starts."""

    name: str
    radius: float
    centre: tuple[float, float, float]
    moving: bool = False


@dataclass(frozen=True)
class CachedPlane:
    """A plane collider, drawn as a square of side ``size`` centred on ``point``."""

    name: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    size: float


COLLIDERS_PATH = WORLD_PATH.AppendChild("Colliders")


def _plane_corners(plane: CachedPlane) -> np.ndarray:
    """The square's corners, counter-clockwise seen from the normal's side."""
    n = np.asarray(plane.normal, dtype=np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    h = plane.size / 2
    p = np.asarray(plane.point, dtype=np.float64)
    return np.array([p - h * u - h * v, p + h * u - h * v, p + h * u + h * v, p - h * u + h * v], np.float32)


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
        if np.shape(s.uvs) != (s.point_count, 2):
            raise ArgumentError(f"shape {s.name!r}: uvs must be ({s.point_count}, 2), got {np.shape(s.uvs)}")


def _create_stage(path: Path) -> Usd.Stage:
    if path.suffix not in _EXTENSIONS:
        raise OutputError(f"cannot write USD cache {path}: the file name must end in {', '.join(_EXTENSIONS)}")
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
                 metadata: dict[str, str] | None = None, colliders: Sequence[CachedSphere | CachedPlane] = (),
                 before_save: Callable[[PointCacheWriter], None] | None = None):
        _check_shapes(shapes)
        if colliders and any(s.name == COLLIDERS_PATH.name for s in shapes):
            raise ArgumentError(f"shape name {COLLIDERS_PATH.name!r} is where the colliders go; rename the shape")
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
        self._holes: dict[int, np.ndarray] = {}  # per tearing shape: the hidden faces last authored
        self._stage: Usd.Stage | None = _create_stage(self.path)

        stage = self._stage
        stage.SetStartTimeCode(self.start_frame)
        stage.SetEndTimeCode(self.start_frame)
        # Both rates, so that a time code is a frame whichever one a reader consults.
        stage.SetTimeCodesPerSecond(fps)
        stage.SetFramesPerSecond(fps)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
        if metadata:
            stage.GetRootLayer().customLayerData = {str(k): str(v) for k, v in metadata.items()}
        stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, WORLD_PATH).GetPrim())

        rope_width = ROPE_WIDTH_METRES / meters_per_unit
        self._prims: list[UsdGeom.PointBased] = []
        for shape in self.shapes:
            prim_path = WORLD_PATH.AppendChild(shape.name)
            if shape.is_rope:
                self._prims.append(self._define_rope(stage, prim_path, shape, rope_width))
            else:
                self._prims.append(self._define_mesh(stage, prim_path, shape))
        self.colliders = tuple(colliders)
        self._moving: list[UsdGeom.XformOp] = []  # translate ops of moving spheres, in collider order
        if self.colliders:
            UsdGeom.Scope.Define(stage, COLLIDERS_PATH)
        for collider in self.colliders:
            prim_path = COLLIDERS_PATH.AppendChild(collider.name)
            if isinstance(collider, CachedSphere):
                sphere = UsdGeom.Sphere.Define(stage, prim_path)
                sphere.CreateRadiusAttr(float(collider.radius))
                r = float(collider.radius)
                sphere.CreateExtentAttr(Vt.Vec3fArray([(-r, -r, -r), (r, r, r)]))
                op = sphere.AddTranslateOp()
                if collider.moving:
                    self._moving.append(op)  # sampled per frame in write_frame
                else:
                    op.Set(tuple(float(c) for c in collider.centre))
            else:
                plane = UsdGeom.Mesh.Define(stage, prim_path)
                corners = _plane_corners(collider)
                plane.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(corners))
                plane.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(Vt.Vec3fArray.FromNumpy(corners)))
                plane.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
                plane.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
                plane.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
                plane.CreateDoubleSidedAttr(True)
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

    @staticmethod
    def _define_mesh(stage: Usd.Stage, prim_path: Sdf.Path, shape: CachedShape) -> UsdGeom.Mesh:
        mesh = UsdGeom.Mesh.Define(stage, prim_path)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(shape.faces.counts))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(shape.faces.indices))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # the fallback, catmullClark, would smooth it
        mesh.CreateDoubleSidedAttr(True)  # cloth is seen from both sides
        mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)  # faces wind counter-clockwise (faces.py)
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(shape.uvs, dtype=np.float32)))
        return mesh

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
            self._prims[k].GetHoleIndicesAttr().Set(Vt.IntArray.FromNumpy(faces), time)
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
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as e:
        return [f"{path}: cannot be opened as USD: {usd_cause(e)}"]

    # USD's own validators: stage metadata, composition, attribute types. Warnings are advice; keep errors.
    context = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    problems = [err.GetErrorAsString() for err in context.Validate(stage)
                if err.GetType() == UsdValidation.ValidationErrorType.Error]
    problems += _check_stage_metadata(stage)
    # Time samples outside [start, end] mean endTimeCode was not kept up to date.
    time_range = (stage.GetStartTimeCode(), stage.GetEndTimeCode())
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            problems += _check_mesh(UsdGeom.Mesh(prim), time_range)
        elif prim.IsA(UsdGeom.BasisCurves):
            curves = UsdGeom.BasisCurves(prim)
            counts = curves.GetCurveVertexCountsAttr().Get()
            problems += _check_points(curves, int(np.sum(counts)) if counts else 0, time_range)
    return problems


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
    st_values = st.Get() if st and st.HasAuthoredValue() else None
    # The point count is the first sample's (_check_points checks that every other sample agrees); a
    # cache with no frame yet has only its UVs to say how many points there will be.
    first = points_attr.Get(times[0]) if times else points_attr.Get()
    n_points = len(first) if first is not None else (len(st_values) if st_values is not None else None)
    if n_points is None:
        return [f"{name}: has neither points nor primvars:st, so its point count is unknown"]

    indices = mesh.GetFaceVertexIndicesAttr().Get() or Vt.IntArray()
    counts = mesh.GetFaceVertexCountsAttr().Get() or Vt.IntArray()
    ok, reason = UsdGeom.Mesh.ValidateTopology(indices, counts, n_points)
    if not ok:
        problems.append(f"{name}: invalid topology: {reason}")
    else:  # USD accepts faces of 0, 1 or 2 corners, which no renderer draws; Faces.validate does not
        try:
            Faces(np.asarray(counts), np.asarray(indices)).validate(n_points, str(name))
        except ValueError as e:
            problems.append(str(e))
    if mesh.GetSubdivisionSchemeAttr().Get() != UsdGeom.Tokens.none:
        problems.append(f"{name}: subdivisionScheme is not 'none', so renderers would smooth the cloth")
    if st_values is not None and len(st_values) != n_points:
        problems.append(f"{name}: primvars:st has {len(st_values)} values for {n_points} points")
    holes = mesh.GetHoleIndicesAttr()
    n_faces = len(counts)
    for t in holes.GetTimeSamples():
        hidden = np.asarray(holes.Get(t), dtype=np.int64)
        if len(hidden) and (hidden.min() < 0 or hidden.max() >= n_faces):
            problems.append(f"{name}: holeIndices at time {t} names a face outside [0, {n_faces})")
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
