"""Reading a point cache the project wrote: its cloths (faces, points per frame, torn faces as holeIndices),
ropes and colliders, as plain numpy. Imports ``pxr`` and numpy only (no Warp, no renderer), so that the PNG/GIF
preview (warp_verlet/apps/preview.py) and the browser player (warp_verlet/apps/cache_player.py) read caches the same way,
with the same errors."""

from __future__ import annotations

import contextlib
import functools
import io
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from pxr import Tf, Usd, UsdGeom

from ..colliders import ColliderKind, kinds as collider_kinds
from ..errors import WarpVerletError, usd_cause, usd_diagnostics
from ..geometry.faces import Faces, as_faces, grid_faces
from .usd_writer import COLLIDERS_PATH

class PreviewError(WarpVerletError):
    """The cache or the preview's options cannot be used as given: a bad argument or input (exit code 2)."""




# --------------------------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class ClothPrim:
    """The static part of one cloth mesh: its faces and, when they form the writer's grid, its shape."""

    prim: UsdGeom.Mesh
    faces: Faces  # triangles, quads, n-gons, or a mix
    grid: tuple[int, int] | None  # (rows, cols) of points when the faces are the writer's regular grid
    points_needed: int  # 1 + the largest vertex index the faces use


@dataclass(frozen=True)
class PointCache:
    """An open cache: what does not change from frame to frame."""

    path: Path
    stage: Usd.Stage
    up_axis: str  # "Y" or "Z"
    fps: float  # time codes per second; a time code is a frame
    frames: tuple[int, ...]  # every frame the cache holds, in order
    cloths: tuple[ClothPrim, ...]
    ropes: tuple[UsdGeom.BasisCurves, ...]
    colliders: tuple[tuple[ColliderKind, Usd.Prim], ...]  # each collider prim and the kind that wrote it


@dataclass(frozen=True)
class FrameGeometry:
    """What one frame draws, in stage coordinates, as plain numpy."""

    frame: int
    seconds: float
    ropes: tuple[np.ndarray, ...]  # (N, 3) polyline of each curve
    spheres: tuple[tuple[np.ndarray, float], ...]  # (centre, radius)
    planes: tuple[np.ndarray, ...]  # (4, 3) corners as authored (drawing clips them to the cloth's box)
    cloth_frames: tuple["ClothFrame", ...] = ()  # each cloth's points and torn faces, undecimated
    meshes: tuple[tuple[np.ndarray, np.ndarray], ...] = ()  # (points (V, 3), triangles (T, 3)) of each mesh


def grid_shape(faces: Faces | np.ndarray, point_count: int) -> tuple[int, int] | None:
    """(rows, cols) of points when ``faces`` (Faces, or an (F, k) array) are exactly the writer's grid
    (``faces.grid_faces``), else None.

    The grid's first face is (0, cols, cols + 1, 1), so it gives cols; the point count then gives rows, and
    the faces are compared with the grid those imply.
    """
    faces = as_faces(faces)
    if len(faces) == 0 or faces.counts[0] != 4 or faces.indices[0] != 0:
        return None
    cols = int(faces.indices[1])
    if cols < 2 or point_count % cols:
        return None
    rows = point_count // cols
    if rows < 2 or len(faces) != (rows - 1) * (cols - 1):  # also keeps a bogus cols from building a huge grid
        return None
    return (rows, cols) if faces == grid_faces(rows, cols) else None


def quiet_usd(read: Callable) -> Callable:
    """``read``, with USD's warnings about a damaged cache kept from stderr: USD prints them with its C++
    function, source file and line, which mean nothing to a user (what cannot be read still raises)."""
    @functools.wraps(read)
    def wrapper(*args, **kwargs):
        with usd_diagnostics():
            return read(*args, **kwargs)
    return wrapper


@quiet_usd
def open_cache(path: str | os.PathLike[str]) -> PointCache:
    """Open a point cache and find its cloths and colliders; PreviewError when it is not one."""
    path = Path(path)
    try:
        found, regular = path.exists(), path.is_file()
    except OSError as exc:  # a name too long, a directory on the way that cannot be searched
        raise PreviewError(f"{path}: cannot look at it ({exc.strerror or exc})") from None
    if not found:
        raise PreviewError(f"{path}: no such file")
    if not regular:
        raise PreviewError(f"{path}: not a file")
    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as e:  # USD's own message names its C++ source line, nothing a user can act on
        raise PreviewError(f"{path}: not a USD file, or a damaged one: USD cannot open it") from e
    if stage is None:
        raise PreviewError(f"{path}: not a USD file, or a damaged one: USD cannot open it")

    cloths, ropes, colliders = [], [], []
    for prim in stage.Traverse():
        under_colliders = prim.GetPath().HasPrefix(COLLIDERS_PATH)
        kind = next((k for k in collider_kinds() if k.owns_prim(prim, under_colliders)), None)
        if kind is not None:
            colliders.append((kind, prim))
        elif prim.IsA(UsdGeom.Mesh):
            cloths.append(_cloth_prim(path, UsdGeom.Mesh(prim)))
        elif prim.IsA(UsdGeom.BasisCurves):
            ropes.append(UsdGeom.BasisCurves(prim))
    if not cloths and not ropes:
        raise PreviewError(f"{path}: no cloth in the cache (expected a UsdGeom.Mesh or BasisCurves under /World)")

    layer = stage.GetRootLayer()
    if layer.HasStartTimeCode() and layer.HasEndTimeCode():
        frames = tuple(range(int(np.ceil(stage.GetStartTimeCode())), int(np.floor(stage.GetEndTimeCode())) + 1))
    else:  # no range authored: the frames the cloths were sampled at
        times = {t for c in cloths for t in c.prim.GetPointsAttr().GetTimeSamples()}
        times |= {t for r in ropes for t in r.GetPointsAttr().GetTimeSamples()}
        frames = tuple(sorted({int(t) for t in times if float(t).is_integer()}))
    up_axis = "Z" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else "Y"
    return PointCache(path=path, stage=stage, up_axis=up_axis, fps=stage.GetTimeCodesPerSecond(),
                      frames=frames or (0,), cloths=tuple(cloths), ropes=tuple(ropes), colliders=tuple(colliders))


def _cloth_prim(path: Path, mesh: UsdGeom.Mesh) -> ClothPrim:
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], dtype=np.int32)  # USD's int: no copy
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], dtype=np.int32)
    try:
        faces = Faces(counts, indices)
        faces.validate(None, f"mesh {mesh.GetPath()}")  # the point count may differ from frame to frame
    except ValueError as e:
        raise PreviewError(f"{path}: {e}") from e
    points = mesh.GetPointsAttr()
    times = points.GetTimeSamples()
    first = _read(path, mesh, "points", lambda: points.Get(times[0]) if times else points.Get(),
                  f"frame {times[0]:g}" if times else "its points")
    return ClothPrim(prim=mesh, faces=faces, grid=grid_shape(faces, len(first) if first is not None else 0),
                     points_needed=int(faces.indices.max()) + 1 if len(faces.indices) else 0)


def _read(path: Path, prim, what: str, get, where: str):
    """``get()``, a read of one attribute of ``prim``; a damaged cache (USD cannot read the value) becomes one
    PreviewError naming the file, the frame and the prim, rather than USD's traceback."""
    noise = io.StringIO()  # a damaged value also makes USD's Python binding print a TypeError of its own
    try:
        with contextlib.redirect_stderr(noise):
            return get()
    except (Tf.ErrorException, TypeError, RuntimeError) as e:  # TypeError: a value USD decoded as the wrong type
        cause = usd_cause(e) if isinstance(e, Tf.ErrorException) else str(e)
        raise PreviewError(f"{path}: {where} is damaged: USD cannot read {prim.GetPath()}.{what} ({cause})") from None


def _finite(path: Path, prim, values, frame: int) -> np.ndarray:
    """``values`` as float64, or a PreviewError when the frame holds NaN or inf (a damaged or diverged cache)."""
    array = np.asarray(values, dtype=np.float64)
    if not np.isfinite(array).all():
        raise PreviewError(f"{path}: frame {frame} is damaged: {prim.GetPath()} holds non-finite values "
                           "(NaN or inf), which cannot be drawn")
    return array


def _to_world(prim: UsdGeom.Xformable, time: Usd.TimeCode, points: np.ndarray) -> np.ndarray:
    """Apply the prim's world transform (the writer authors none, so usually nothing to do)."""
    m = np.array(prim.ComputeLocalToWorldTransform(time))
    if np.array_equal(m, np.eye(4)):
        return points
    return points @ m[:3, :3] + m[3, :3]  # USD matrices act on row vectors


@dataclass(frozen=True)
class ClothFrame:
    """One cloth at one frame: its points in stage coordinates and the faces torn away (holeIndices)."""

    cloth: ClothPrim
    points: np.ndarray  # (V, 3) float64
    hidden: np.ndarray  # face indices, sorted; empty when nothing is torn
    grid: tuple[int, int] | None  # (rows, cols) when this frame's points form the writer's grid


@quiet_usd
def read_cloths(cache: PointCache, frame: int) -> list[ClothFrame]:
    """Each cloth's points and torn faces at ``frame`` (holeIndices held between their samples); a cloth with
    no points or no faces at that frame is left out."""
    time = Usd.TimeCode(frame)
    where = f"frame {frame}"
    out = []
    for cloth in cache.cloths:
        points = _read(cache.path, cloth.prim, "points", lambda: cloth.prim.GetPointsAttr().Get(time), where)
        if points is None or len(cloth.faces) == 0:
            continue
        if len(points) < cloth.points_needed:
            raise PreviewError(f"{cache.path}: mesh {cloth.prim.GetPath()} has {len(points)} points at frame {frame}, "
                               f"but its faces use {cloth.points_needed}")
        # The grid was recognised on the first sample; a mesh whose point count changes is drawn face by face.
        grid = cloth.grid if cloth.grid and len(points) == cloth.grid[0] * cloth.grid[1] else None
        hidden = _read(cache.path, cloth.prim, "holeIndices", lambda: cloth.prim.GetHoleIndicesAttr().Get(time),
                       where)  # None or empty when the mesh never tears
        hidden = np.asarray(hidden if hidden is not None else (), np.int64)
        if cloth.prim.GetFaceVertexCountsAttr().GetNumTimeSamples() > 1:  # torn faces removed from the topology
            hidden = np.union1d(hidden, _removed_faces(cache.path, cloth, time, where))
        world = _to_world(cloth.prim, time, _finite(cache.path, cloth.prim, points, frame))
        out.append(ClothFrame(cloth, world, hidden, grid))
    return out


def _removed_faces(path: Path, cloth: ClothPrim, time: Usd.TimeCode, where: str) -> np.ndarray:
    """The faces of the cloth's whole topology (its default value) that its topology at ``time`` leaves out: a
    cache written with torn_faces = "remove" samples the topology without the torn faces, in their order."""
    counts = _read(path, cloth.prim, "faceVertexCounts", lambda: cloth.prim.GetFaceVertexCountsAttr().Get(time), where)
    indices = _read(path, cloth.prim, "faceVertexIndices", lambda: cloth.prim.GetFaceVertexIndicesAttr().Get(time),
                    where)
    try:
        now = Faces(np.asarray(counts or [], np.int32), np.asarray(indices or [], np.int32))
    except ValueError as e:
        raise PreviewError(f"{path}: {where}: {e}") from e
    whole = cloth.faces
    if len(now) == len(whole):
        return np.zeros(0, np.int64)
    uniform_whole, uniform_now = whole.as_uniform(), now.as_uniform()
    if uniform_whole is not None and uniform_now is not None and uniform_whole.shape[1] == uniform_now.shape[1]:
        row = np.dtype((np.void, uniform_whole.dtype.itemsize * uniform_whole.shape[1]))
        kept = np.isin(np.ascontiguousarray(uniform_whole).view(row).ravel(),
                       np.ascontiguousarray(uniform_now.astype(uniform_whole.dtype)).view(row).ravel())
    else:  # faces of several sizes: compared one by one
        def split(f: Faces):
            return [tuple(c) for c in np.split(f.indices, np.cumsum(f.counts)[:-1])]
        present = set(split(now))
        kept = np.array([face in present for face in split(whole)], bool)
    return np.flatnonzero(~kept)


@quiet_usd
def read_frame(cache: PointCache, frame: int) -> FrameGeometry:
    """One frame of the cache as numpy, with holeIndices applied (held between their samples)."""
    time = Usd.TimeCode(frame)
    where = f"frame {frame}"
    cloth_frames = read_cloths(cache, frame)
    ropes = []
    for curves in cache.ropes:
        points = _read(cache.path, curves, "points", lambda: curves.GetPointsAttr().Get(time), where)
        if points is None:
            continue
        points = _to_world(curves, time, _finite(cache.path, curves, points, frame))
        counts = curves.GetCurveVertexCountsAttr().Get(time) or [len(points)]
        ropes += np.split(points, np.cumsum(counts)[:-1])
    drawn: dict[str, list] = {"spheres": [], "planes": [], "meshes": []}  # the kinds' prims as drawing primitives
    reader = _FrameReader(cache.path, frame, time, where)
    for kind, prim in cache.colliders:
        for primitive, item in kind.read_prim(prim, reader).items():
            drawn[primitive].append(item)
    return FrameGeometry(frame=frame, seconds=frame / cache.fps, ropes=tuple(ropes),
                         spheres=tuple(drawn["spheres"]), planes=tuple(drawn["planes"]),
                         cloth_frames=tuple(cloth_frames), meshes=tuple(drawn["meshes"]))


@dataclass(frozen=True)
class _FrameReader:
    """The reading helpers above, for one frame, as a collider kind's ``read_prim`` gets them
    (colliders.FrameReader)."""

    path: Path
    frame: int
    time: Usd.TimeCode
    where: str

    def attribute(self, prim, name: str, get):
        return _read(self.path, prim, name, get, self.where)

    def finite(self, prim, values) -> np.ndarray:
        return _finite(self.path, prim, values, self.frame)

    def to_world(self, prim, points: np.ndarray) -> np.ndarray:
        return _to_world(prim, self.time, points)
