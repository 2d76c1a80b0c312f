"""One panel of the preview, ray traced on the CPU by Mitsuba 3 (its ``scalar_rgb`` variant): every pixel sees
the nearest surface (a per-pixel depth test, where matplotlib's mplot3d sorted whole polygons), a key light
casts shadows, and a 2 x 2 grid of rays per pixel smooths the edges. Nothing here needs a GPU, a display or a
system OpenGL library: the Mitsuba wheel holds the whole renderer.

The frame is described in plain numpy (``FrameGeometry`` from the cache reader); this module builds a Mitsuba
scene of it, with a camera fitted to that frame's cloths (``fit_camera``), renders it, and returns 8-bit sRGB
pixels. A second pass lights the same scene from the camera (a fill light), so that surfaces in the key light's
shadow keep their colour and shape rather than going black. The result is the same for the same input: the rays
are not jittered.

This module never imports warp.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import mitsuba
import numpy as np

from ..output.cache_reader import ClothFrame, FrameGeometry
from .display_mesh import fan_triangles, grid_lines
from ..geometry.faces import Faces

# Seen from above and in front, off to the right: a vertical cloth in the XY plane of a Y-up stage faces the
# camera at 30 degrees instead of edge-on, and a horizontal one still shows its folds. Elevation above the
# horizon and azimuth about the vertical axis, both in degrees, measured as matplotlib's view_init does, so
# the new preview looks at a cache from where the old one did.
VIEW_ELEVATION, VIEW_AZIMUTH = 20.0, -60.0
# The key light comes from over the camera's shoulder: this much higher and further round than the camera.
LIGHT_ELEVATION_OFFSET, LIGHT_AZIMUTH_OFFSET = 25.0, 20.0
# Shares of a surface's colour that the key light gives a face turned to it, and the fill light from the
# camera gives a face turned to the camera.
KEY_LIGHT, FILL_LIGHT = 0.75, 0.3
RAYS_PER_PIXEL = 4  # a 2 x 2 grid: edges smoothed, and the same image every time
MARGIN = 0.06  # the fraction of the panel's half-size left free around the cloth
# Content closer to the cloth than this many cloth sizes (its bounding box's diagonal) is framed with it: a
# sphere the cloth lies on, but not a collider it left far behind.
NEARBY = 0.5
# A part of a cloth holding less than this share of its area, on one side of the rest and far from it, is left
# out of the framing (see _bulk).
SLIVER_AREA, BULK_GROWTH = 0.08, 0.5
PLANE_PAD = 0.15  # the ground drawn beyond the framed content, as a fraction of the content's largest side
ROPE_RADIUS_PX = 1.0  # a rope is drawn as a tube this many pixels thick on each side of its axis
ROPE_SIDES = 6

BACKGROUND = (1.0, 1.0, 1.0)  # sRGB
CLOTH_COLOURS = ((0.80, 0.33, 0.24), (0.23, 0.47, 0.72), (0.36, 0.62, 0.33), (0.85, 0.62, 0.20))  # sRGB
ROPE_COLOUR = (0.15, 0.15, 0.15)
SPHERE_COLOUR = (0.70, 0.72, 0.76)
PLANE_COLOUR = (0.86, 0.86, 0.84)


def _mitsuba():
    """Mitsuba with its CPU variant chosen (on first use: choosing it loads the renderer's library)."""
    if mitsuba.variant() != "scalar_rgb":
        mitsuba.set_variant("scalar_rgb")  # the one variant every wheel has that needs no LLVM and no GPU
    return mitsuba


def srgb_to_linear(c) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


# ---------------------------------------------------------------------------------------------- camera


def up_vector(up_axis: str) -> np.ndarray:
    return np.array([0.0, 0.0, 1.0]) if up_axis == "Z" else np.array([0.0, 1.0, 0.0])


def _direction(elevation: float, azimuth: float, up_axis: str) -> np.ndarray:
    """The unit vector towards a point at ``elevation`` and ``azimuth`` (matplotlib's convention, z vertical),
    in stage coordinates: a Y-up stage's (x, y, z) is matplotlib's (x, -z, y), a rotation."""
    e, a = np.radians(elevation), np.radians(azimuth)
    d = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])  # matplotlib's axes
    return d if up_axis == "Z" else np.array([d[0], d[2], -d[1]])


def view_direction(up_axis: str) -> np.ndarray:
    """Unit vector from what is seen towards the camera."""
    return _direction(VIEW_ELEVATION, VIEW_AZIMUTH, up_axis)


def light_direction(up_axis: str) -> np.ndarray:
    """Unit vector from a surface towards the key light."""
    return _direction(VIEW_ELEVATION + LIGHT_ELEVATION_OFFSET, VIEW_AZIMUTH + LIGHT_AZIMUTH_OFFSET, up_axis)


@dataclass(frozen=True)
class Camera:
    """An orthographic camera: it looks along -``towards_eye`` at ``centre``; the image spans ``half_width``
    to either side of the centre along ``right`` and ``half_height`` along ``up`` (stage units)."""

    centre: np.ndarray
    towards_eye: np.ndarray
    right: np.ndarray
    up: np.ndarray
    half_width: float
    half_height: float
    distance: float  # from the eye to the centre: beyond everything drawn

    def to_pixels(self, points: np.ndarray, width: int, height: int) -> np.ndarray:
        """(N, 2) pixel coordinates (x to the right, y down, pixel centres at half-integers) of stage points."""
        rel = np.asarray(points, np.float64) - self.centre
        u, v = rel @ self.right, rel @ self.up
        return np.stack([(u / self.half_width + 1) * width / 2, (1 - v / self.half_height) * height / 2], axis=-1)


def fit_camera(subject: np.ndarray, everything: np.ndarray, up_axis: str, aspect: float) -> Camera:
    """The camera that shows the points ``subject`` (N, 3) as large as the panel allows (width / height =
    ``aspect``), with ``MARGIN`` around them, and stands beyond every point of ``everything``."""
    towards_eye = view_direction(up_axis)
    right = np.cross(up_vector(up_axis), towards_eye)
    right /= np.linalg.norm(right)
    up = np.cross(towards_eye, right)
    u, v = subject @ right, subject @ up
    (u0, u1), (v0, v1) = (u.min(), u.max()), (v.min(), v.max())
    half_u, half_v = (u1 - u0) / 2, (v1 - v0) / 2
    size = max(half_u, half_v * aspect, 1e-6 * max(1.0, float(np.abs(subject).max())))  # a point still gets a view
    half_width = size * (1 + MARGIN)
    depth = subject @ towards_eye
    centre = (u0 + u1) / 2 * right + (v0 + v1) / 2 * up + (depth.min() + depth.max()) / 2 * towards_eye
    reach = np.linalg.norm(everything - centre, axis=1).max() if len(everything) else 0.0
    return Camera(centre=centre, towards_eye=towards_eye, right=right, up=up, half_width=half_width,
                  half_height=half_width / aspect, distance=2 * reach + 4 * half_width + 1.0)


# ------------------------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class TriangleMesh:
    points: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (T, 3) uint32


def cloth_mesh(cloth: ClothFrame, max_grid_quads: int) -> TriangleMesh:
    """The triangles drawn of one cloth at one frame: torn faces left out (a hole shows what is behind it).

    A grid with more than ``max_grid_quads`` quads a side is drawn through evenly spaced grid lines (both
    hems always kept, so the outline is exact), a coarse quad hidden when any fine face under it is torn.
    The caller sets the limit from the panel's size in pixels, so a quad still covers about a pixel."""
    hidden = np.zeros(len(cloth.cloth.faces), bool)
    index = cloth.hidden[(cloth.hidden >= 0) & (cloth.hidden < len(hidden))]
    hidden[index] = True
    if cloth.grid is not None:
        rows, cols = cloth.grid
        ri, ci = grid_lines(rows - 1, max_grid_quads), grid_lines(cols - 1, max_grid_quads)
        points = cloth.points.reshape(rows, cols, 3)[np.ix_(ri, ci)].reshape(-1, 3)
        fine = hidden.reshape(rows - 1, cols - 1)
        coarse = np.logical_or.reduceat(np.logical_or.reduceat(fine, ri[:-1], axis=0), ci[:-1], axis=1)
        n = len(ci)
        r, c = np.nonzero(~coarse)
        a = r * n + c
        triangles = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
        return TriangleMesh(points.astype(np.float32), triangles.astype(np.uint32))
    faces: Faces = cloth.cloth.faces
    triangles, face = fan_triangles(faces)
    return TriangleMesh(cloth.points.astype(np.float32), triangles[~hidden[face]].astype(np.uint32))


def tube_mesh(polyline: np.ndarray, radius: float) -> TriangleMesh:
    """A rope: a tube of ``ROPE_SIDES`` sides around the polyline (N, 3)."""
    polyline = np.asarray(polyline, np.float64)
    if len(polyline) < 2:
        return TriangleMesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32))
    tangent = np.gradient(polyline, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    helper = np.where(np.abs(tangent[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    side = np.cross(tangent, helper)
    side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-12)
    other = np.cross(tangent, side)
    angle = 2 * np.pi * np.arange(ROPE_SIDES) / ROPE_SIDES
    ring = (np.cos(angle)[None, :, None] * side[:, None] + np.sin(angle)[None, :, None] * other[:, None])
    points = (polyline[:, None] + radius * ring).reshape(-1, 3)
    i, k = np.meshgrid(np.arange(len(polyline) - 1), np.arange(ROPE_SIDES), indexing="ij")
    a, b = i * ROPE_SIDES + k, i * ROPE_SIDES + (k + 1) % ROPE_SIDES
    triangles = np.concatenate([np.stack([a, a + ROPE_SIDES, b + ROPE_SIDES], -1).reshape(-1, 3),
                                np.stack([a, b + ROPE_SIDES, b], -1).reshape(-1, 3)])
    return TriangleMesh(points.astype(np.float32), triangles.astype(np.uint32))


def clip_plane(corners: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """The part of a rectangular plane quad under the box [lo, hi] (its footprint on the plane), so that a
    ground plane meant to look infinite is drawn as far as the content reaches. None when they do not overlap."""
    origin = corners[0]
    u, v = corners[1] - origin, corners[-1] - origin
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    if lu == 0 or lv == 0:
        return None
    u, v = u / lu, v / lv
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pu, pv = (box - origin) @ u, (box - origin) @ v
    u0, u1 = max(pu.min(), 0.0), min(pu.max(), lu)
    v0, v1 = max(pv.min(), 0.0), min(pv.max(), lv)
    if u1 <= u0 or v1 <= v0:
        return None
    return origin + np.array([u0 * u + v0 * v, u1 * u + v0 * v, u1 * u + v1 * v, u0 * u + v1 * v])


@dataclass(frozen=True)
class Panel:
    """What one panel draws: its camera, and the frame's shapes in plain numpy."""

    camera: Camera
    cloths: tuple[TriangleMesh, ...]
    ropes: tuple[TriangleMesh, ...]
    spheres: tuple[tuple[np.ndarray, float], ...]
    planes: tuple[np.ndarray, ...]  # (4, 3) corners, clipped to the framed content
    up_axis: str
    meshes: tuple[TriangleMesh, ...] = ()  # triangle-mesh colliders


def _box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points.min(axis=0), points.max(axis=0)


def _bulk(mesh: TriangleMesh, up_axis: str) -> np.ndarray:
    """The drawn points of a cloth that the camera frames: all of them, except slivers far from where most of
    its area is. A flag torn from its pole leaves a thin strip at the pins; framing the strip and the flag
    together would make the flag small again. The bulk is the box, on the image's axes, holding the middle
    ``1 - 2 * SLIVER_AREA`` of the area (by the triangles' centres); every triangle whose centre lies within
    ``BULK_GROWTH`` of its size of that box is kept whole, so an untorn cloth is framed whole."""
    points = mesh.points.astype(np.float64)
    corners = points[mesh.triangles]
    area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    if area.sum() <= 0:
        return points[np.unique(mesh.triangles)]
    towards_eye = view_direction(up_axis)
    right = np.cross(up_vector(up_axis), towards_eye)
    right /= np.linalg.norm(right)
    axes = np.stack([right, np.cross(towards_eye, right)], axis=1)  # the image's horizontal and vertical
    centroid = corners.mean(axis=1) @ axes
    order = np.argsort(centroid, axis=0)
    cumulative = np.cumsum(area[order], axis=0) / area.sum()
    lo = centroid[order[np.argmax(cumulative >= SLIVER_AREA, axis=0), [0, 1]], [0, 1]]
    hi = centroid[order[np.argmax(cumulative >= 1 - SLIVER_AREA, axis=0), [0, 1]], [0, 1]]
    reach = BULK_GROWTH * (hi - lo).max()
    keep = np.all((centroid >= lo - reach) & (centroid <= hi + reach), axis=1)
    return points[np.unique(mesh.triangles[keep])]  # the kept triangles whole, corners and all


def frame_panel(geometry: FrameGeometry, up_axis: str, width: int, height: int) -> Panel:
    """The panel of one frame: its cloths and ropes framed as large as the panel allows (the camera follows
    them, however far they travelled), with the spheres and meshes near them; planes clipped to that content."""
    max_quads = max(width, height)  # about one grid cell per pixel: smooth hems, and no more work than that
    cloths = [cloth_mesh(c, max_quads) for c in geometry.cloth_frames]
    subject = [_bulk(m, up_axis) for m in cloths if len(m.triangles)]
    subject += [np.asarray(r, np.float64) for r in geometry.ropes if len(r)]
    spheres = list(geometry.spheres)
    mesh_boxes = [np.stack(_box(p)) for p, t in geometry.meshes if len(t)]  # each mesh's (2, 3) bounding box
    if subject:
        points = np.concatenate(subject).astype(np.float64)
        lo, hi = _box(points)
        reach = NEARBY * max(float(np.linalg.norm(hi - lo)), 1e-6)
        near = [(c, r) for c, r in spheres if np.all(c + r >= lo - reach) and np.all(c - r <= hi + reach)]
        near_boxes = [b for b in mesh_boxes if np.all(b[1] >= lo - reach) and np.all(b[0] <= hi + reach)]
    elif spheres or mesh_boxes:  # every face torn away and no rope: show the colliders rather than nothing
        points, near, near_boxes = np.zeros((0, 3)), spheres, mesh_boxes
    else:
        points, near, near_boxes = np.zeros((1, 3)), [], []
    framed = np.concatenate([points] + [np.stack([c - r, c + r]) for c, r in near] + near_boxes)
    lo, hi = _box(framed)
    pad = PLANE_PAD * max(float((hi - lo).max()), 1e-6)
    planes = [q for q in (clip_plane(p, lo - pad, hi + pad) for p in geometry.planes) if q is not None]
    everything = np.concatenate([framed] + [np.stack([c - r, c + r]) for c, r in spheres] + planes + mesh_boxes)
    camera = fit_camera(framed, everything, up_axis, width / height)
    rope_radius = ROPE_RADIUS_PX * 2 * camera.half_width / width
    ropes = [tube_mesh(r, rope_radius) for r in geometry.ropes]
    meshes = tuple(TriangleMesh(p.astype(np.float32), t.astype(np.uint32)) for p, t in geometry.meshes if len(t))
    return Panel(camera, tuple(cloths), tuple(ropes), tuple(spheres), tuple(planes), up_axis, meshes)


# ------------------------------------------------------------------------------------------- rendering


def _diffuse(mi, srgb) -> dict:
    colour = [float(x) for x in srgb_to_linear(srgb)]
    # Cloth is seen from both sides; "twosided" gives the back of each face the same diffuse response.
    return {"type": "twosided", "material": {"type": "diffuse", "reflectance": {"type": "rgb", "value": colour}}}


def _mesh(mi, name: str, mesh: TriangleMesh, srgb, smooth: bool):
    # Only the vertices some triangle uses: a torn-out region leaves vertices in no face, which have no normal
    # (Mitsuba would say so on the terminal at every frame).
    used, triangles = np.unique(mesh.triangles, return_inverse=True)
    points = mesh.points[used]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(_diffuse(mi, srgb))
    shape = mi.Mesh(name, len(points), len(mesh.triangles), props=props, has_vertex_normals=smooth)
    params = mi.traverse(shape)
    params["vertex_positions"] = type(params["vertex_positions"])(points.ravel())
    params["faces"] = type(params["faces"])(triangles.reshape(-1).astype(mesh.triangles.dtype))
    params.update()  # also computes the vertex normals from the faces, when smooth
    return shape


def render_panel(panel: Panel, width: int, height: int) -> np.ndarray:
    """(height, width, 3) uint8 sRGB pixels of ``panel``."""
    mi = _mitsuba()
    camera = panel.camera
    eye = camera.centre + camera.distance * camera.towards_eye
    to_world = mi.ScalarTransform4f().look_at(origin=[float(x) for x in eye], target=[float(x) for x in camera.centre],
                                             up=[float(x) for x in camera.up])
    to_world = to_world @ mi.ScalarTransform4f().scale([float(camera.half_width), float(camera.half_width), 1.0])
    # A light's irradiance makes a face turned to it as bright as that share of its colour (a diffuse surface
    # reflects albedo * E / pi).
    towards_light = light_direction(panel.up_axis)
    scene: dict = {
        "type": "scene",
        # "direct" with no BSDF samples: one shadow ray per camera ray towards the one directional light, which
        # is exact (no noise). Mitsuba's aov integrator would give each pixel's albedo for an ambient term, but
        # in the scalar variant it made a frame about three times slower than a second pass of this one.
        "integrator": {"type": "direct", "bsdf_samples": 0, "emitter_samples": 1},
        "sensor": {
            "type": "orthographic",
            "near_clip": 1e-3 * camera.distance,
            "far_clip": 4 * camera.distance,
            "to_world": to_world,
            "film": {"type": "hdrfilm", "width": int(width), "height": int(height), "pixel_format": "rgba",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "stratified", "sample_count": RAYS_PER_PIXEL, "jitter": False},
        },
        "key": {"type": "directional", "to_world": _light_to_world(mi, towards_light),
                "irradiance": {"type": "rgb", "value": KEY_LIGHT * np.pi}},
    }
    for i, mesh in enumerate(panel.cloths):
        if len(mesh.triangles):
            scene[f"cloth{i}"] = _mesh(mi, f"cloth{i}", mesh, CLOTH_COLOURS[i % len(CLOTH_COLOURS)], smooth=True)
    for i, mesh in enumerate(panel.ropes):
        if len(mesh.triangles):
            scene[f"rope{i}"] = _mesh(mi, f"rope{i}", mesh, ROPE_COLOUR, smooth=True)
    for i, (centre, radius) in enumerate(panel.spheres):
        scene[f"sphere{i}"] = {"type": "sphere", "center": [float(x) for x in centre], "radius": float(radius),
                               "bsdf": _diffuse(mi, SPHERE_COLOUR)}
    for i, mesh in enumerate(panel.meshes):
        scene[f"mesh{i}"] = _mesh(mi, f"mesh{i}", mesh, SPHERE_COLOUR, smooth=False)
    for i, quad in enumerate(panel.planes):
        plane = TriangleMesh(quad.astype(np.float32), np.array([[0, 1, 2], [0, 2, 3]], np.uint32))
        scene[f"plane{i}"] = _mesh(mi, f"plane{i}", plane, PLANE_COLOUR, smooth=False)
    built = mi.load_dict(scene)
    key = close_cracks(np.asarray(mi.render(built), dtype=np.float64))  # R G B A, linear, premultiplied
    # The fill: the same light turned to shine from the camera, with FILL_LIGHT's share. Everything the camera
    # sees is lit by it (an orthographic camera's rays and the light's are parallel), so no surface in the
    # key light's shadow goes black. The scene and its ray-tracing structure are reused.
    params = mi.traverse(built)
    params["key.to_world"] = _light_to_world(mi, camera.towards_eye)
    params["key.irradiance.value"] = FILL_LIGHT * np.pi
    params.update()
    fill = close_cracks(np.asarray(mi.render(built), dtype=np.float64))
    alpha = key[..., 3:4]
    # Premultiplied by coverage, so the edges of the cloth blend into the background.
    linear = key[..., :3] + fill[..., :3] + (1 - alpha) * srgb_to_linear(BACKGROUND)
    return np.round(linear_to_srgb(linear) * 255).astype(np.uint8)


def _light_to_world(mi, towards_light: np.ndarray):
    """A directional light's transform: it shines along its local +z, here away from ``towards_light``."""
    direction = [float(-x) for x in towards_light]
    helper = [0.0, 0.0, 1.0] if abs(direction[2]) < 0.9 else [1.0, 0.0, 0.0]
    return mi.ScalarTransform4f().look_at(origin=[0.0, 0.0, 0.0], target=direction, up=helper)


def close_cracks(image: np.ndarray) -> np.ndarray:
    """``image`` (H, W, C; channel 3 the coverage, every channel premultiplied by it) with its cracks closed.

    The ray-triangle test is not watertight: now and then a ray through the shared edge of two triangles hits
    neither, and a pixel in the middle of a cloth shows a speck of background. A pixel partly covered while
    all eight neighbours are fully covered is such a crack (a real hole, a torn face, is a quad of the grid
    drawn at most one per pixel, so it uncovers its neighbours' edges too); it takes the average of its rays
    that hit, as if the missing one had hit too."""
    alpha = image[..., 3]
    full = alpha >= 1 - 1e-6
    padded = np.pad(full, 1, constant_values=False)
    height, width = alpha.shape
    surrounded = np.ones_like(full)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            if dy != 1 or dx != 1:
                surrounded &= padded[dy:dy + height, dx:dx + width]
    crack = surrounded & ~full & (alpha >= 0.5)
    if crack.any():
        image = image.copy()
        image[crack] /= alpha[crack][:, None]
    return image


def render_frame(geometry: FrameGeometry, up_axis: str, width: int, height: int) -> np.ndarray:
    """(height, width, 3) uint8 sRGB pixels of one frame, framed on its cloths."""
    return render_panel(frame_panel(geometry, up_axis, width, height), width, height)


def subject_points(geometries: Sequence[FrameGeometry]) -> np.ndarray:
    """Every cloth and rope point of ``geometries`` (tests and benchmarks measure framing with it)."""
    chunks = [c.points for g in geometries for c in g.cloth_frames] + [r for g in geometries for r in g.ropes]
    return np.concatenate(chunks) if chunks else np.zeros((0, 3))
