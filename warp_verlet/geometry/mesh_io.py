"""Reading a cloth mesh from a file: trimesh for OBJ, PLY, STL, OFF, GLB/GLTF and the rest of its formats, pxr for
a prim of a USD file.

Both give a :class:`~warp_verlet.geometry.mesh_cloth.SourceMesh` in the scene's frame: metres and the scene's axes,
after the scene's own scale, rotation and translation. USD points are taken in world space (the prim's
local-to-world transform at its first time sample) and converted to metres with the stage's
``metersPerUnit``; ``SourceMesh.to_local`` maps simulated points back into the prim's own space, which an
override layer needs. Axes are never swapped: a Z-up asset is simulated Z-up (give gravity along -Z).

trimesh triangulates every polygon as it loads (its OBJ and PLY readers split quads and n-gons into
triangles), so a mesh read through it is made of triangles and gets no shear sticks. USD keeps the faces as
authored, quads and n-gons included.

A USD asset must compose cleanly: a sublayer, reference or payload that is missing, is not a USD layer, or
closes a cycle (USD warns, skips it and goes on) is a MeshError naming the asset and the broken layer. Every
file the asset composes or names (:func:`layer_dependencies`: sublayers, references and payloads, recursively,
including unselected variants and paths not created yet) is kept in ``SourceMesh.dependencies``, so that no run
output may replace one. USD's own diagnostics are captured while a USD file is read (errors.usd_diagnostics) and
shown without its C++ function names, source files and line numbers.

Only the reader a scene needs is imported: trimesh for mesh files, pxr for USD. A reader may need a package
that is not installed (trimesh reads an OBJ with UVs through Pillow); that is said as such, naming the package
to install, not as a mesh that cannot be read.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import plain_usd_text, usd_cause, usd_diagnostics
from .faces import Faces
from .mesh_cloth import MeshError, SourceMesh

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


class UsdWarning(UserWarning):
    """Something USD reported while a USD mesh was read that does not stop the read (an asset path it names
    that cannot be resolved, say), in USD's words without its C++ function, file and line."""


def transform_matrix(translate=(0.0, 0.0, 0.0), rotate_degrees=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(4, 4) column-vector affine: scale, then rotate about X, then Y, then Z (fixed axes), then translate."""
    rx, ry, rz = np.radians(rotate_degrees)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    about_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    about_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    about_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = about_z @ about_y @ about_x @ np.diag(np.asarray(scale, np.float64))
    m[:3, 3] = translate
    return m


def apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 3) through a (4, 4) column-vector affine matrix."""
    return points @ matrix[:3, :3].T + matrix[:3, 3]


FLOAT32_MAX = float(np.finfo(np.float32).max)


def _point_text(point) -> str:
    return "(" + ", ".join(f"{float(v):g}" for v in point) + ")"


def to_scene(description: str, matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The file's points moved into the scene's frame by ``matrix``, once each is known to be finite in the file
    (a non-finite coordinate is reported as the file has it, before the transform spreads NaN to the others)
    and within float32's range after the move (the simulation and its cache hold positions in float32)."""
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise MeshError(f"{description}: vertex {bad} is not a finite point: {_point_text(points[bad])} in the "
                        f"file ({int((~finite).sum())} such vertices)")
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported below, as such
        moved = apply(matrix, points)
    outside = ~(np.abs(moved) <= FLOAT32_MAX).all(axis=1)
    if outside.any():
        bad = int(np.flatnonzero(outside)[0])
        raise MeshError(f"{description}: vertex {bad} is at {_point_text(moved[bad])} m in the scene, beyond "
                        f"float32's range (+-{FLOAT32_MAX:.3g}), in which positions are simulated and cached "
                        f"({int(outside.sum())} such vertices)")
    return moved


# The package to install for a module whose import name differs from its name on PyPI.
PACKAGE_OF_MODULE = {"PIL": "Pillow", "pxr": "usd-core", "yaml": "PyYAML", "collada": "pycollada",
                     "skimage": "scikit-image", "sklearn": "scikit-learn"}
# The module a ModuleNotFoundError names: trimesh keeps a failed optional import and raises it again when a
# loader needs the module, re-created from its message alone, so ``exc.name`` is None there.
_MISSING_MODULE = re.compile(r"No module named '([^']+)'|import of (\S+) halted")


def missing_package(path: Path, exc: ModuleNotFoundError) -> MeshError:
    """The error for a reader that needs a package that is not installed: the package and how to install it."""
    module = exc.name
    if not module:
        found = _MISSING_MODULE.search(str(exc))
        module = next((m for m in found.groups() if m), None) if found else None
    if not module:
        return MeshError(f"{path}: reading it needs a Python package that is not installed ({exc})")
    package = PACKAGE_OF_MODULE.get(module.split(".")[0], module.split(".")[0])
    return MeshError(f"reading {path.name} needs the Python package {package}, which is not installed "
                     f"(pip install {package.lower()})")


def read_mesh(path: Path, prim: str | None, transform: np.ndarray, named: tuple[tuple[str, str], ...] = ()) -> SourceMesh:
    """The mesh at ``path`` (a USD ``prim``, which USD files need and other formats refuse), moved by
    ``transform`` into the scene's frame. ``named``: ("primvar" or "subset", name) vertex sets to look up
    for pins (USD only). A package the reader needs and cannot import is a MeshError naming the package."""
    try:
        return _read_mesh(path, prim, transform, named)
    except ModuleNotFoundError as exc:
        raise missing_package(path, exc) from None


def _read_mesh(path: Path, prim: str | None, transform: np.ndarray, named: tuple[tuple[str, str], ...]) -> SourceMesh:
    is_usd = path.suffix.lower() in USD_SUFFIXES
    if not path.is_file():
        raise MeshError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    if is_usd:
        if prim is None:
            raise MeshError(f"{path}: a USD file holds many prims; name the mesh with prim = \"/path/to/Mesh\"")
        with usd_diagnostics() as reported:  # a composition problem is read from the stage: a MeshError
            mesh = _read_usd(path, prim, transform, named)
        for text in dict.fromkeys(reported):  # what else USD had to say, without its C++ locations
            warnings.warn(f"{path}: {text}", UsdWarning, stacklevel=4)
        return mesh
    if prim is not None:
        raise MeshError(f"{path}: prim is for USD files only; this is a {path.suffix or 'suffix-less'} file")
    if named:
        kind, name = named[0]
        raise MeshError(f"{path}: pins by {kind} ({name!r}) need a USD file; this is a {path.suffix} file")
    return _read_trimesh(path, transform)


def _read_trimesh(path: Path, transform: np.ndarray) -> SourceMesh:
    import trimesh

    suffix = path.suffix.lower().lstrip(".")
    if suffix not in trimesh.available_formats():
        raise MeshError(f"{path}: trimesh cannot read .{suffix} files (it reads "
                        f"{', '.join(sorted(trimesh.available_formats()))}; or give a USD file and a prim)")
    if suffix == "obj":
        _check_obj_vertex_numbers(path)
    try:
        # process=False and maintain_order: the vertices and faces as the file has them, nothing merged or
        # reordered, so the cache lines up with the file (welding is ours, and keeps the vertex order).
        loaded = trimesh.load(str(path), process=False, maintain_order=True, force="mesh")
    except ModuleNotFoundError:
        raise  # a package the loader needs, not a damaged file: read_mesh names it
    except Exception as exc:  # trimesh raises many types for a damaged file; all mean "cannot read"
        raise MeshError(f"{path}: cannot read the mesh ({type(exc).__name__}: {exc})") from None
    points = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), np.float64).reshape(-1, 3)
    triangles = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), np.int64).reshape(-1, 3)
    uv = getattr(getattr(loaded, "visual", None), "uv", None)
    uvs = np.asarray(uv, np.float32) if uv is not None and len(uv) == len(points) and len(points) else None
    return SourceMesh(description=str(path), file=path, points=to_scene(str(path), transform, points),
                      faces=Faces.uniform(triangles),
                      uvs=uvs, uv_interpolation="vertex" if uvs is not None else None)


def composition_problems(stage) -> list[str]:
    """What USD could not compose on an open stage, one plain line each: sublayer cycles, reference or payload
    cycles, and sublayers, references or payloads that are missing or not USD layers (USD skips each with a
    warning and goes on, and a cache made from what is left is not the asset)."""
    return [" ".join(plain_usd_text(str(error)).split()) for error in stage.GetCompositionErrors()]


def layer_dependencies(path: Path) -> tuple[Path, ...]:
    """Every file the USD file at ``path`` composes or names, recursively: its sublayers, references and payloads
    (unloaded payloads and unselected variants included), the other assets they name, and the paths it names that
    do not exist yet (a file written there later would become part of the asset). None may be a run's output."""
    from pxr import Tf, UsdUtils

    try:
        with usd_diagnostics():  # an unresolved path is returned (and reported to any enclosing usd_diagnostics)
            layers, assets, unresolved = UsdUtils.ComputeAllDependencies(str(path))
    except Tf.ErrorException as exc:  # a layer that is not composed now (an unselected variant's) cannot be read
        raise MeshError(f"{path}: a broken USD asset: a layer it names cannot be read ({usd_cause(exc)})") from None
    found = [Path(layer.realPath) for layer in layers if layer.realPath]
    found += [Path(asset) for asset in (*assets, *unresolved) if asset]
    return tuple(dict.fromkeys(found))


# A face ("f") line naming vertex 0, which OBJ does not have: it numbers vertices from 1 (and from -1 back from
# the last), and trimesh would take 0 silently as another vertex.
_OBJ_VERTEX_ZERO = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[ \t])[+-]?0+(?=[/ \t\r\n]|$)", re.M)


def _check_obj_vertex_numbers(path: Path) -> None:
    text = path.read_bytes()
    found = _OBJ_VERTEX_ZERO.search(text)
    if found:
        line = text.count(b"\n", 0, found.start()) + 1
        end = text.find(b"\n", found.start())
        face = text[found.start():end if end >= 0 else len(text)]
        raise MeshError(f"{path}: line {line}: face {face.decode('utf-8', 'replace').strip()!r} names vertex 0; OBJ "
                        "numbers vertices from 1 (or from -1 back from the last)")


def _read_usd(path: Path, prim_path: str, transform: np.ndarray, named) -> SourceMesh:
    from pxr import Sdf, Tf, Usd, UsdGeom

    if not Sdf.Path.IsValidPathString(prim_path) or not Sdf.Path(prim_path).IsAbsolutePath():
        raise MeshError(f"{path}: prim {prim_path!r} is not an absolute prim path like \"/World/Cloth\"")
    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise MeshError(f"{path}: cannot open as USD ({usd_cause(exc)})") from None
    if stage is None:
        raise MeshError(f"{path}: cannot open as USD")
    problems = composition_problems(stage)
    if problems:
        more = f" (and {len(problems) - 1} more composition problems)" if len(problems) > 1 else ""
        raise MeshError(f"{path}: a broken USD asset: {problems[0]}{more}")
    prim = stage.GetPrimAtPath(prim_path)
    if not prim.IsValid():
        meshes = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)][:5]
        raise MeshError(f"{path}: no prim at {prim_path} (meshes in the file: {', '.join(meshes) or 'none'})")
    if not prim.IsA(UsdGeom.Mesh):
        raise MeshError(f"{path}: prim {prim_path} is a {prim.GetTypeName() or 'typeless prim'}, not a Mesh")
    mesh = UsdGeom.Mesh(prim)
    times = mesh.GetPointsAttr().GetTimeSamples()
    time = Usd.TimeCode(times[0]) if times else Usd.TimeCode.Default()
    raw = mesh.GetPointsAttr().Get(time)
    counts = mesh.GetFaceVertexCountsAttr().Get(time)
    indices = mesh.GetFaceVertexIndicesAttr().Get(time)
    points = np.asarray(raw if raw is not None else [], np.float64).reshape(-1, 3)
    faces = Faces(np.asarray(counts if counts is not None else [], np.int64),
                  np.asarray(indices if indices is not None else [], np.int64))
    # Gf matrices act on row vectors (p' = p M): transpose for the column-vector convention used here.
    local_to_world = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time), np.float64).T
    to_metres = np.diag([UsdGeom.GetStageMetersPerUnit(stage)] * 3 + [1.0])
    to_scene_matrix = transform @ to_metres @ local_to_world
    uvs, interpolation = _read_uvs(mesh, len(points), len(faces.indices), time)
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    vertex_sets = {key: _named_vertices(path, mesh, faces, len(points), *key, time) for key in named}
    description = f"{path} prim {prim_path}"
    return SourceMesh(description=description, file=path, points=to_scene(description, to_scene_matrix, points),
                      faces=faces,
                      uvs=uvs, uv_interpolation=interpolation, left_handed=left, prim_path=prim_path,
                      to_local=np.linalg.inv(to_scene_matrix), named_vertices=vertex_sets,
                      dependencies=layer_dependencies(path))


def _read_uvs(mesh, points: int, corners: int, time):
    """primvars:st flattened (indexed primvars expanded), if it is per vertex or per face corner."""
    from pxr import UsdGeom

    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    if not st or not st.HasAuthoredValue():
        return None, None
    values = st.ComputeFlattened(time)
    if values is None:
        return None, None
    uvs = np.asarray(values, np.float32).reshape(-1, 2)
    interpolation = st.GetInterpolation()
    if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and len(uvs) == points:
        return uvs, "vertex"
    if interpolation == UsdGeom.Tokens.faceVarying and len(uvs) == corners:
        return uvs, "faceVarying"
    return None, None  # constant or uniform UVs carry no texture layout worth keeping


def _named_vertices(path: Path, mesh, faces: Faces, points: int, kind: str, name: str, time) -> np.ndarray:
    """The vertices a primvar marks (non-zero values) or a GeomSubset holds (its points, or its faces' corners)."""
    from pxr import UsdGeom

    where = f"{path} prim {mesh.GetPath()}"
    face_of_corner = np.repeat(np.arange(len(faces)), faces.counts)
    if kind == "primvar":
        primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar(name)
        if not primvar or not primvar.HasAuthoredValue():
            names = [p.GetPrimvarName() for p in UsdGeom.PrimvarsAPI(mesh).GetPrimvars()]
            raise MeshError(f"{where}: no primvar {name!r} (its primvars: {', '.join(names) or 'none'})")
        values = np.asarray(primvar.ComputeFlattened(time), np.float64)
        marked = np.flatnonzero(values.reshape(len(values), -1).any(axis=1)) if values.size else np.zeros(0, np.int64)
        interpolation = primvar.GetInterpolation()
        if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and len(values) == points:
            return marked
        if interpolation == UsdGeom.Tokens.uniform and len(values) == len(faces):
            return np.unique(faces.indices[np.isin(face_of_corner, marked)])
        if interpolation == UsdGeom.Tokens.faceVarying and len(values) == len(faces.indices):
            return np.unique(faces.indices[marked])
        raise MeshError(f"{where}: primvar {name!r} is {interpolation} with {len(values)} values; pins need one "
                        "value per vertex, per face or per face corner")
    subsets = {s.GetPrim().GetName(): s for s in UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(mesh))}
    if name not in subsets:
        raise MeshError(f"{where}: no GeomSubset {name!r} (its subsets: {', '.join(sorted(subsets)) or 'none'})")
    subset = subsets[name]
    members = np.asarray(subset.GetIndicesAttr().Get(time) or [], np.int64)
    element = subset.GetElementTypeAttr().Get()
    if element == UsdGeom.Tokens.face:
        if len(members) and (members.min() < 0 or members.max() >= len(faces)):
            raise MeshError(f"{where}: GeomSubset {name!r} names a face outside [0, {len(faces)})")
        return np.unique(faces.indices[np.isin(face_of_corner, members)])
    if len(members) and (members.min() < 0 or members.max() >= points):
        raise MeshError(f"{where}: GeomSubset {name!r} names a point outside [0, {points})")
    return np.unique(members)


class UsdAnimation:
    """How a USD Mesh prim moves over time, for a collider: its local-to-world transform (the prim's and its
    ancestors' xform ops) and its points, where they are time-sampled. Time is the scene's, in seconds: a time
    code is seconds × the stage's timeCodesPerSecond (time code 0 is the scene's start), and between samples
    USD's own interpolation applies (``world_at`` and ``points_at`` ask the stage). Open only while a collider is
    read (``read_usd_animation``)."""

    def __init__(self, description: str, stage, prim):
        from pxr import UsdGeom

        self.description = description
        self.stage = stage
        self.prim = prim
        self.codes_per_second = float(stage.GetTimeCodesPerSecond())
        self.to_metres = np.diag([UsdGeom.GetStageMetersPerUnit(stage)] * 3 + [1.0])
        transform_codes: set[float] = set()
        at = prim
        while at and not at.IsPseudoRoot():
            if at.IsA(UsdGeom.Xformable):
                transform_codes.update(UsdGeom.Xformable(at).GetTimeSamples())
            at = at.GetParent()
        self.transform_times = self._seconds(transform_codes) if len(transform_codes) > 1 else ()
        mesh = UsdGeom.Mesh(prim)
        point_codes = mesh.GetPointsAttr().GetTimeSamples()
        self.point_times = self._seconds(point_codes) if len(point_codes) > 1 else ()
        self._check_topology(mesh, point_codes)

    def _seconds(self, codes) -> tuple[float, ...]:
        return tuple(float(c) / self.codes_per_second for c in sorted(codes))

    def _code(self, seconds: float):
        from pxr import Usd

        return Usd.TimeCode(seconds * self.codes_per_second)

    def _when(self, seconds: float) -> str:
        return f"at time code {seconds * self.codes_per_second:g} ({seconds:g} s)"

    def _check_topology(self, mesh, point_codes) -> None:
        """The faces may not change over time, and every points sample has as many points as the first."""
        counts_attr, indices_attr = mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr()
        for attr, name in ((counts_attr, "faceVertexCounts"), (indices_attr, "faceVertexIndices")):
            codes = attr.GetTimeSamples()
            if len(codes) > 1:
                first = np.asarray(attr.Get(codes[0]))
                for code in codes[1:]:
                    if not np.array_equal(np.asarray(attr.Get(code)), first):
                        raise MeshError(f"{self.description}: its topology changes over time ({name} at time code "
                                        f"{code:g} differs from time code {codes[0]:g}); a mesh collider keeps its "
                                        "faces, only its points and transform may be time-sampled")
        if len(point_codes) > 1:
            attr = mesh.GetPointsAttr()
            first = len(attr.Get(point_codes[0]) or [])
            for code in point_codes[1:]:
                count = len(attr.Get(code) or [])
                if count != first:
                    raise MeshError(f"{self.description}: its topology changes over time ({count} points at time "
                                    f"code {code:g}, {first} at time code {point_codes[0]:g}); a mesh collider "
                                    "keeps its points and faces, only their positions may be time-sampled")

    @property
    def moves(self) -> bool:
        return bool(self.transform_times or self.point_times)

    def world_at(self, seconds: float) -> np.ndarray:
        """(4, 4) column-vector affine at ``seconds``: the prim's points to metres in USD's world."""
        from pxr import UsdGeom

        matrix = np.asarray(UsdGeom.Xformable(self.prim).ComputeLocalToWorldTransform(self._code(seconds)),
                            np.float64).T
        if not np.isfinite(matrix).all():
            raise MeshError(f"{self.description}: its local-to-world transform is not finite {self._when(seconds)}")
        return self.to_metres @ matrix

    def points_at(self, seconds: float) -> np.ndarray:
        """(V, 3) float64: the prim's points in its own space at ``seconds``, as authored (file units)."""
        from pxr import UsdGeom

        raw = UsdGeom.Mesh(self.prim).GetPointsAttr().Get(self._code(seconds))
        points = np.asarray(raw if raw is not None else [], np.float64).reshape(-1, 3)
        finite = np.isfinite(points).all(axis=1)
        if not finite.all():
            bad = int(np.flatnonzero(~finite)[0])
            raise MeshError(f"{self.description}: vertex {bad} is not a finite point {self._when(seconds)}: "
                            f"{_point_text(points[bad])} in the file ({int((~finite).sum())} such vertices)")
        return points


def read_usd_animation(path: Path, prim_path: str) -> UsdAnimation:
    """The animation of the Mesh prim ``prim_path`` of the USD file at ``path`` (read_mesh has read and checked
    the prim at its first sample already)."""
    from pxr import Usd

    with usd_diagnostics():  # read_mesh reported what USD had to say of this file
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
        return UsdAnimation(f"{path} prim {prim_path}", stage, stage.GetPrimAtPath(prim_path))
