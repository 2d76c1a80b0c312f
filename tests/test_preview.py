"""warp-verlet preview: caches written by PointCacheWriter (no simulation) rendered to PNG and GIF, the
polygons it draws (holes, decimation), frame selection, and the command line's answers to bad input."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image
from pxr import Usd, UsdGeom, Vt

from warp_verlet.apps import preview
from warp_verlet.apps import preview_render as render
from warp_verlet.output.cache_reader import ClothFrame, ClothPrim
from warp_verlet.apps.cli import main, parse_frame_slice, parse_size
from warp_verlet.geometry.faces import Faces
from warp_verlet.output.usd_writer import CachedPlane, CachedShape, CachedSphere, PointCacheWriter

from meshes import HOUSE, HOUSE_POINTS  # tests/meshes.py (pytest puts tests/ on sys.path)

FRAMES = 6  # frames 0..6


def grid_faces(rows: int, cols: int) -> np.ndarray:
    # The writer's (and topology.build_cloth's) layout: (r,c) -> (r+1,c) -> (r+1,c+1) -> (r,c+1).
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (r * cols + c).ravel()
    return np.stack([a, a + cols, a + cols + 1, a + 1], axis=1).astype(np.int32)


def grid_points(rows: int, cols: int, sag: float = 0.0) -> np.ndarray:
    """A vertical 1 m cloth in the XY plane, top edge at y = 1, bulging along +z by ``sag``."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    x, y = c / (cols - 1) - 0.5, 1.0 - r / (rows - 1)
    z = sag * np.sin(np.pi * c / (cols - 1)) * (1.0 - y)
    return np.stack([x, y, z], axis=-1).reshape(-1, 3).astype(np.float32)


def write_cache(path, rows: int = 3, cols: int = 3, frames: int = FRAMES, colliders=(), up_axis: str = "Y",
                rope: bool = False):
    shapes = [CachedShape("cloth", grid_faces(rows, cols), np.zeros((rows * cols, 2), np.float32), rows * cols)]
    if rope:
        shapes.append(CachedShape("rope", np.zeros((0, 4), np.int32), np.zeros((4, 2), np.float32), 4))
    moving = sum(isinstance(c, CachedSphere) and c.moving for c in colliders)
    with PointCacheWriter(path, shapes, fps=30.0, up_axis=up_axis, colliders=colliders) as writer:
        for f in range(frames + 1):
            points = [grid_points(rows, cols, sag=0.05 * f)]
            if rope:
                points.append(np.stack([np.full(4, 0.8), np.linspace(1.0, 0.4, 4), np.zeros(4)], -1))
            writer.write_frame(f, points, np.tile([0.1 * f, 0.5, 0.3], (moving, 1)))
    return path


def set_holes(path, samples: dict[int, list[int]], prim: str = "/World/cloth") -> None:
    """Author holeIndices as the tearing writer does: sampled only at the frames where the set changes."""
    stage = Usd.Stage.Open(str(path))
    attr = UsdGeom.Mesh(stage.GetPrimAtPath(prim)).CreateHoleIndicesAttr()
    for frame, faces in samples.items():
        attr.Set(Vt.IntArray(faces), Usd.TimeCode(frame))
    stage.Save()


def as_set(polygons: np.ndarray) -> set:
    return {tuple(map(tuple, np.round(np.asarray(p, np.float64), 6).tolist())) for p in polygons}


@pytest.fixture
def cache(tmp_path):
    colliders = [CachedSphere("ball", 0.15, (0.0, 0.5, 0.3), moving=True),
                 CachedPlane("ground", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 1000.0)]
    return write_cache(tmp_path / "cache.usdc", rows=9, cols=9, colliders=colliders, rope=True)


def load_rgb(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)


# ------------------------------------------------------------------------------------------- images


@pytest.mark.slow
def test_png_has_the_requested_size_and_is_not_blank(cache, capsys):
    out = cache.parent / "p.png"
    assert main(["preview", str(cache), "-o", str(out), "--size", "320x240"]) == 0
    assert str(out) in capsys.readouterr().out
    image = Image.open(out)
    assert image.format == "PNG" and image.size == (320, 240)
    pixels = load_rgb(out)
    assert pixels.std() > 20  # a blank or single-colour canvas has (almost) none
    # The cloth's red is there: some pixels are clearly redder than they are blue.
    assert ((pixels[..., 0] - pixels[..., 2]) > 60).sum() > 100


@pytest.mark.slow
def test_png_default_size_and_single_frame(cache):
    default, single = cache.parent / "d.png", cache.parent / "s.png"
    assert main(["preview", str(cache), "-o", str(default)]) == 0
    assert main(["preview", str(cache), "-o", str(single), "--frames", "3"]) == 0
    assert Image.open(default).size == preview.DEFAULT_SIZE[".png"] == Image.open(single).size
    assert not np.array_equal(load_rgb(default), load_rgb(single))  # 4 panels vs 1


@pytest.mark.slow
def test_gif_has_one_image_per_frame_that_change(cache):
    out = cache.parent / "a.gif"
    assert main(["preview", str(cache), "-o", str(out), "--size", "200x160", "--frames", "0:7:2"]) == 0
    image = Image.open(out)
    assert image.format == "GIF" and image.size == (200, 160)
    assert image.n_frames == 4  # frames 0, 2, 4, 6
    frames = []
    for k in range(image.n_frames):
        image.seek(k)
        frames.append(np.asarray(image.convert("RGB"), dtype=np.float64))
    assert all(f.std() > 20 for f in frames)
    assert not np.array_equal(frames[0], frames[-1])  # the cloth sags and the sphere moves


def test_gif_is_thinned_to_at_most_120_frames(tmp_path):
    path = write_cache(tmp_path / "long.usdc", frames=200)
    cache = preview.open_cache(path)
    shown = preview.evenly_spaced(preview.select_frames(None, cache.frames), preview.MAX_GIF_FRAMES)
    assert len(shown) == 120 and shown[0] == 0 and shown[-1] == 200 and shown == sorted(set(shown))


# ---------------------------------------------------------------------------------- what gets drawn


def test_hidden_faces_are_not_drawn_and_holes_are_held_between_samples(tmp_path):
    path = write_cache(tmp_path / "torn.usdc", rows=3, cols=3)  # 2 x 2 faces
    set_holes(path, {0: [], 3: [1]})
    cache = preview.open_cache(path)
    for frame, hidden in ((0, []), (2, []), (3, [1]), (5, [1])):  # sampled at 3, held at 5
        cloth = preview.read_frame(cache, frame).cloth_frames[0]
        assert cloth.hidden.tolist() == hidden, frame
        np.testing.assert_allclose(cloth.points, grid_points(3, 3, sag=0.05 * frame), rtol=0, atol=1e-7)
        # What the renderer draws: every face but the hidden one, two triangles a quad.
        drawn = render.frame_panel(preview.read_frame(cache, frame), "Y", 64, 64).cloths[0]
        assert len(drawn.triangles) == 2 * (4 - len(hidden)), frame


def test_a_corner_torn_out_renders_without_a_word_from_the_renderer(tmp_path, capfd):
    """A torn-out corner leaves its vertex in no face; the renderer must not be handed it (Mitsuba prints a
    warning about vertices without a normal at every frame otherwise, at the C++ level: capfd sees it)."""
    path = write_cache(tmp_path / "corner.usdc", rows=4, cols=4)
    set_holes(path, {0: [0]})  # face 0 alone holds vertex 0
    assert main(["preview", str(path), "-o", str(tmp_path / "corner.png"), "--size", "64x64"]) == 0
    captured = capfd.readouterr()
    assert "invalid" not in captured.out + captured.err and "WARN" not in captured.out + captured.err


def test_a_mesh_that_never_tears_draws_every_face(tmp_path):
    path = write_cache(tmp_path / "whole.usdc", rows=4, cols=5)
    cache = preview.open_cache(path)
    assert not cache.cloths[0].prim.GetHoleIndicesAttr().HasAuthoredValue()
    assert cache.cloths[0].grid == (4, 5)
    cloth = preview.read_frame(cache, 2).cloth_frames[0]
    assert cloth.hidden.size == 0 and cloth.grid == (4, 5) and cloth.points.shape == (20, 3)


def test_only_the_writer_s_own_grid_is_taken_for_a_grid():
    faces, points = grid_faces(10, 12), grid_points(10, 12)
    assert preview.grid_shape(faces, len(points)) == (10, 12)
    shuffled = faces[np.random.default_rng(0).permutation(len(faces))]
    assert preview.grid_shape(shuffled, len(points)) is None
    assert preview.grid_shape(np.zeros((0, 4), int), 5) is None
    triangles = Faces.uniform(np.array([[0, 1, 2], [0, 2, 4], [1, 5, 6]]))
    assert preview.grid_shape(triangles, len(HOUSE_POINTS)) is None


def house_points(frame: int) -> np.ndarray:
    """The house in the XY plane, leaning further back along -z frame by frame."""
    p = HOUSE_POINTS.copy()
    p[:, 2] = -0.1 * frame * p[:, 1]
    return p


def house_polygons(frame: int, faces: list[int]) -> set:
    points = house_points(frame)
    return as_set([points[HOUSE.indices[HOUSE.offsets[f]:HOUSE.offsets[f + 1]]] for f in faces])


def write_house_cache(path):
    shape = CachedShape("cloth", HOUSE, np.zeros((len(HOUSE_POINTS), 2), np.float32), len(HOUSE_POINTS), tears=True)
    with PointCacheWriter(path, [shape], fps=30.0) as writer:
        for f in range(FRAMES + 1):
            writer.write_frame(f, [house_points(f)], hidden_faces=[[0] if f >= 3 else None])
    return path


def test_a_mixed_mesh_is_drawn_face_by_face_and_its_hidden_pentagon_left_out(tmp_path):
    cache = preview.open_cache(write_house_cache(tmp_path / "house.usdc"))
    assert cache.cloths[0].grid is None and cache.cloths[0].faces == HOUSE
    # The pentagon is hidden from frame 3 on: sampled at 3, held at 6. The renderer fans each face it draws
    # into corners - 2 triangles: 3 + 2 + 1 whole, 2 + 1 without the pentagon.
    for frame, hidden, triangles in ((0, [], 6), (2, [], 6), (3, [0], 3), (6, [0], 3)):
        geometry = preview.read_frame(cache, frame)
        assert geometry.cloth_frames[0].hidden.tolist() == hidden, frame
        np.testing.assert_allclose(geometry.cloth_frames[0].points, house_points(frame), rtol=0, atol=1e-7)
        assert len(render.frame_panel(geometry, "Y", 64, 64).cloths[0].triangles) == triangles, frame


@pytest.mark.slow
def test_a_mixed_mesh_renders_to_png(tmp_path, capsys):
    cache = write_house_cache(tmp_path / "house.usdc")
    whole, torn = tmp_path / "whole.png", tmp_path / "torn.png"
    assert main(["preview", str(cache), "-o", str(whole), "--size", "320x240", "--frames", "0"]) == 0
    assert main(["preview", str(cache), "-o", str(torn), "--size", "320x240", "--frames", "3"]) == 0
    assert "error" not in capsys.readouterr().err
    for png in (whole, torn):
        pixels = load_rgb(png)
        assert Image.open(png).size == (320, 240) and pixels.std() > 20
        assert ((pixels[..., 0] - pixels[..., 2]) > 60).sum() > 100  # the cloth's red
    # Where the pentagon was (its square part, convex), the torn picture shows the background. The single
    # panel of a 320 x 240 image lies below its title, above the caption: the camera is the panel's.
    caption = min(preview.CAPTION_ROOM_PX, 240 // 20)
    title = min(preview.TITLE_ROOM_PX, (240 - caption) // 10)
    height = 240 - caption - title
    panel = render.frame_panel(preview.read_frame(preview.open_cache(cache), 3), "Y", 320, height)
    square = panel.camera.to_pixels(house_points(3)[[0, 1, 2, 4]], 320, height)
    hole = inside(square, 320, height)
    assert hole.sum() > 1000
    assert is_background(load_rgb(torn)[title:title + height][hole]).all()
    assert is_cloth_red(load_rgb(whole)[title:title + height][hole]).mean() > 0.5  # (its own framing)


def geometry_of(points, faces, hidden=(), spheres=(), planes=(), frame=0) -> "preview.FrameGeometry":
    """A FrameGeometry of one cloth, built without a cache: what the renderer is handed for one frame."""
    faces = faces if isinstance(faces, Faces) else Faces.uniform(np.asarray(faces))
    points = np.asarray(points, np.float64)
    prim = ClothPrim(prim=None, faces=faces, grid=preview.grid_shape(faces, len(points)),
                     points_needed=int(faces.indices.max()) + 1)
    cloth = ClothFrame(prim, points, np.asarray(sorted(hidden), np.int64), prim.grid)
    return preview.FrameGeometry(frame=frame, seconds=frame / 30, ropes=(), spheres=tuple(spheres),
                                 planes=tuple(planes), cloth_frames=(cloth,))


def inside(polygon_px: np.ndarray, width: int, height: int, shrink: float = 1.5) -> np.ndarray:
    """(height, width) mask of the pixel centres inside a convex polygon (pixel coordinates, either winding)
    by more than ``shrink`` pixels: away from the antialiased edge."""
    y, x = np.mgrid[0:height, 0:width] + 0.5
    signs = []
    for a, b in zip(polygon_px, np.roll(polygon_px, -1, axis=0)):
        edge = b - a
        signs.append(((x - a[0]) * edge[1] - (y - a[1]) * edge[0]) / np.linalg.norm(edge))
    signs = np.array(signs)
    return np.all(signs > shrink, axis=0) | np.all(signs < -shrink, axis=0)


def is_cloth_red(pixels: np.ndarray) -> np.ndarray:
    pixels = np.asarray(pixels, np.float64)
    return (pixels[..., 0] - pixels[..., 2]) > 60


def is_sphere_grey(pixels: np.ndarray) -> np.ndarray:
    pixels = np.asarray(pixels, np.float64)
    return (np.ptp(pixels, axis=-1) < 25) & (pixels.mean(axis=-1) < 235)  # grey, darker than the background


def is_background(pixels: np.ndarray) -> np.ndarray:
    return np.all(np.asarray(pixels) >= 250, axis=-1)


def panel_of(geometry, width=320, height=240):
    panel = render.frame_panel(geometry, "Y", width, height)
    return panel, render.render_panel(panel, width, height)


QUAD = np.array([[-0.5, 1.0, 0.0], [-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 1.0, 0.0]])  # facing +z, the camera


def test_a_cloth_in_front_of_a_sphere_hides_it_pixel_by_pixel():
    # A sphere just behind a quad, sticking out past its right edge. mplot3d's painter's algorithm sorted whole
    # polygons by their centres and let sphere facets show through the cloth; a depth test per pixel does not.
    sphere = (np.array([0.45, 0.5, -0.22]), 0.2)
    panel, pixels = panel_of(geometry_of(QUAD, [[0, 1, 2, 3]], spheres=[sphere]))
    quad = inside(panel.camera.to_pixels(QUAD, 320, 240), 320, 240)
    assert quad.sum() > 5000
    assert is_cloth_red(pixels[quad]).all()  # every pixel inside the quad's silhouette is cloth
    assert not is_sphere_grey(pixels[quad]).any()
    assert is_sphere_grey(pixels[~quad]).sum() > 100  # and the sphere is drawn where it sticks out


def test_a_torn_face_is_a_hole_showing_the_background():
    rows = cols = 4  # 3 x 3 faces; the middle one (index 4) torn
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    points = np.stack([c / 3 - 0.5, 1 - r / 3, 0 * r], -1).reshape(-1, 3)
    faces = grid_faces(rows, cols)
    panel, pixels = panel_of(geometry_of(points, faces, hidden=[4]))
    hole = inside(panel.camera.to_pixels(points[faces[4]], 320, 240), 320, 240)
    kept = inside(panel.camera.to_pixels(points[faces[0]], 320, 240), 320, 240)
    assert hole.sum() > 300 and kept.sum() > 300
    assert is_background(pixels[hole]).all()
    assert is_cloth_red(pixels[kept]).all()


def test_each_panel_is_framed_on_its_own_frame(tmp_path):
    # The cloth travels 100 m between frames 0 and 6: framing both frames together made it a speck.
    path = write_cache(tmp_path / "flying.usdc", rows=9, cols=9)
    stage = Usd.Stage.Open(str(path))
    attr = UsdGeom.Mesh(stage.GetPrimAtPath("/World/cloth")).GetPointsAttr()
    attr.Set(Vt.Vec3fArray.FromNumpy(grid_points(9, 9, sag=0.3) + np.float32([100, 0, 0])), Usd.TimeCode(6))
    stage.Save()
    del stage
    out = tmp_path / "two.png"
    assert main(["preview", str(path), "-o", str(out), "--frames", "0:7:6", "--size", "640x340"]) == 0
    pixels = load_rgb(out)
    title, caption = preview.TITLE_ROOM_PX, min(preview.CAPTION_ROOM_PX, 340 // 20)
    for left in (0, 320):
        panel = pixels[title:340 - caption, left:left + 320]
        ys, xs = np.nonzero(is_cloth_red(panel))
        # The cloth spans its panel's width or height, less the margin around it (MARGIN of each half).
        fill = max((np.ptp(xs) + 1) / panel.shape[1], (np.ptp(ys) + 1) / panel.shape[0])
        assert fill > 0.9, (left, fill)


def test_a_piece_torn_away_is_framed_without_the_strip_left_at_the_pins():
    # A 32-column flag torn along its second column: the strip at the pole (1/32 of the area) stays, the rest
    # has blown 5 m away. Framing both made the flag small again; the panel follows the flag.
    rows, cols = 9, 33
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    points = np.stack([c / 32, 1.5 - r / 16, 0 * r], -1).astype(np.float64)
    points[:, 2:] += [5.0, -1.0, 2.0]  # everything right of the tear
    faces = grid_faces(rows, cols)
    torn = [row * (cols - 1) + 1 for row in range(rows - 1)]  # the second face of every row
    width, height = 320, 240
    panel = render.frame_panel(geometry_of(points.reshape(-1, 3), faces, hidden=torn), "Y", width, height)
    flag = panel.camera.to_pixels(points[:, 2:].reshape(-1, 3), width, height)
    assert flag.min() >= 0 and flag[:, 0].max() <= width and flag[:, 1].max() <= height  # all of it in view
    fill = max(np.ptp(flag[:, 0]) / width, np.ptp(flag[:, 1]) / height)
    assert fill > 0.9, fill
    strip = panel.camera.to_pixels(points[:, 0], width, height)
    assert not ((strip >= 0) & (strip <= [width, height])).all(axis=1).any()  # the strip is out of the frame
    # Untorn, the same cloth is framed whole: every point in view.
    whole = render.frame_panel(geometry_of(points.reshape(-1, 3), faces), "Y", width, height)
    every = whole.camera.to_pixels(points.reshape(-1, 3), width, height)
    assert every.min() >= 0 and every[:, 0].max() <= width and every[:, 1].max() <= height


@pytest.mark.slow
def test_a_fine_grid_has_a_smooth_hem():
    # A 256 x 256 grid whose bottom hem waves 12 times across: drawn as the old 64 x 64 coarse grid, the hem
    # was a chord through every 4th point, off the curve by several pixels; now it follows the curve.
    n = 256
    r, c = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    x = c / n - 0.5
    hem = 0.06 * np.sin(2 * np.pi * 12 * x)
    y = 1 - r / n * (1 - hem)
    points = np.stack([x, y, 0 * x], -1).reshape(-1, 3)
    width = height = 400
    panel, pixels = panel_of(geometry_of(points, grid_faces(n + 1, n + 1)), width, height)
    # The hem's path on the image, finely sampled, and the cloth's coverage of each pixel from its blue
    # channel, in linear light (the film averages a pixel's rays in linear light): the white background is 1,
    # the flat, evenly lit cloth its interior's value.
    fine_x = np.linspace(-0.5, 0.5, 40001)
    curve = panel.camera.to_pixels(np.stack([fine_x, 0.06 * np.sin(2 * np.pi * 12 * fine_x), 0 * fine_x], -1),
                                   width, height)
    blue = render.srgb_to_linear(pixels[..., 2] / 255)
    cloth_blue = np.median(blue[is_cloth_red(pixels)])
    coverage = np.clip((1 - blue) / (1 - cloth_blue), 0, 1)
    errors = []
    for col in range(int(curve[:, 0].min()) + 3, int(curve[:, 0].max()) - 3):
        # Each pixel's 2 x 2 rays sample two sub-columns: where the hem crosses each of them, on average.
        crossings = np.interp([col + 0.25, col + 0.75], curve[:, 0], curve[:, 1])
        window = np.arange(int(crossings.min()) - 4, int(crossings.max()) + 5)
        # The cloth lies above the hem: its coverage of the window ends where the hem crosses, on average.
        edge = window[0] + coverage[window, col].sum()
        errors.append(edge - crossings.mean())
    assert len(errors) > 250
    assert np.abs(errors).max() < 1.0, np.abs(errors).max()


@pytest.mark.slow
@pytest.mark.parametrize("n", [48, 256])
def test_a_cloth_shows_no_specks_of_background(n):
    # Rays through the shared edges of two triangles can miss both: a speck of background in the middle of
    # the cloth. A smoothly bent, smoothly lit cloth must have no pixel much lighter than those around it.
    r, c = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    bend = r / n
    points = np.stack([c / n - 0.5 + 0.1 * bend, 1 - 0.8 * bend, 0.6 * bend**2], -1).reshape(-1, 3)
    panel, pixels = panel_of(geometry_of(points, grid_faces(n + 1, n + 1)), 600, 560)
    red = is_cloth_red(pixels)
    core = red.copy()  # cloth pixels with cloth for two pixels all round: away from the outline
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            core &= np.roll(red, (dy, dx), axis=(0, 1))
    assert core.sum() > 50000
    blue = pixels[..., 2].astype(np.float64)
    around = np.median([np.roll(blue, shift, axis) for shift in (-2, 2) for axis in (0, 1)], axis=0)
    assert np.abs(blue - around)[core].max() <= 8


@pytest.mark.slow
def test_a_large_grid_is_drawn_at_about_one_quad_per_pixel():
    n = 1024
    faces, points = grid_faces(n + 1, n + 1), grid_points(n + 1, n + 1, sag=0.2)
    geometry = geometry_of(points, faces)
    panel = render.frame_panel(geometry, "Y", 480, 300)
    mesh = panel.cloths[0]
    assert len(mesh.triangles) == 2 * 480 * 480  # the panel's larger side, in quads, each side
    # Both hems and every corner are kept exactly.
    corners = points.reshape(n + 1, n + 1, 3)[[0, 0, -1, -1], [0, -1, 0, -1]]
    assert all((np.abs(mesh.points - corner).max(axis=1) < 1e-6).any() for corner in corners)
    small = render.frame_panel(geometry_of(grid_points(65, 65), grid_faces(65, 65)), "Y", 480, 300)
    assert len(small.cloths[0].triangles) == 2 * 64 * 64  # a grid smaller than the panel is drawn whole


def test_flat_faces_of_any_size_are_shaded_alike():
    # Per-pixel lighting of a flat mesh of a pentagon, a quad and a triangle, tilted: one colour throughout.
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, 0.8, 0.6], [0.0, -0.6, 0.8]])  # a plane facing neither axis
    points = HOUSE_POINTS @ tilt.T + [3.0, -2.0, 5.0]
    panel, pixels = panel_of(geometry_of(points, HOUSE))
    red = is_cloth_red(pixels)
    core = red & np.roll(red, 2, 0) & np.roll(red, -2, 0) & np.roll(red, 2, 1) & np.roll(red, -2, 1)
    assert core.sum() > 2000
    assert np.ptp(pixels[core], axis=0).max() <= 2


def test_a_huge_ground_plane_is_clipped_to_the_cloth(cache):
    c = preview.open_cache(cache)
    geometry = preview.read_frame(c, 0)
    panel = render.frame_panel(geometry, c.up_axis, 320, 240)
    assert 2 * panel.camera.half_width < 3.0  # the 1000 m ground would have made it 1000
    (ground,) = panel.planes
    assert np.allclose(ground[:, 1], 0.0)  # still the ground, at its height
    xs = geometry.cloth_frames[0].points[:, 0]
    assert ground[:, 0].min() < xs.min() and ground[:, 0].max() > xs.max()  # and it reaches past the cloth
    pixels = render.render_panel(panel, 320, 240)
    # The ground's colour, lit by the key light and the fill light from the camera, each at its angle (Lambert).
    light = render.KEY_LIGHT * render.light_direction("Y")[1] + render.FILL_LIGHT * render.view_direction("Y")[1]
    plane = render.linear_to_srgb(render.srgb_to_linear(render.PLANE_COLOUR) * light) * 255
    assert (np.abs(pixels - plane).max(axis=-1) < 3).sum() > 1000  # the ground is drawn, lit from above


def test_the_stage_up_axis_is_up_in_the_picture_and_nothing_is_mirrored():
    for axis, up in (("Y", [0, 1, 0]), ("Z", [0, 0, 1])):
        camera = render.fit_camera(np.eye(3), np.eye(3), axis, 1.0)
        assert camera.up @ up > 0.9 and abs(camera.right @ up) < 1e-12  # vertical stays vertical
        # right x up = towards the eye: a right-handed camera, so fronts stay fronts.
        np.testing.assert_allclose(np.cross(camera.right, camera.up), camera.towards_eye, atol=1e-12)
    # A Y-up stage is seen as the same stage turned Z-up would be: a rotation taking z to y.
    turn = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]])  # (x, y, z) -> (x, z, -y)
    np.testing.assert_allclose(turn @ render.view_direction("Z"), render.view_direction("Y"), atol=1e-12)


# --------------------------------------------------------------------------------- frame selection


@pytest.mark.parametrize("text, expected", [
    ("0:10:2", slice(0, 10, 2)), ("5:", slice(5, None, None)), (":8", slice(None, 8, None)),
    ("::3", slice(None, None, 3)), (":", slice(None, None, None)), ("7", slice(7, 8, None)),
    (" 2:4 ", slice(2, 4, None)),
])
def test_frame_slice_syntax(text, expected):
    assert parse_frame_slice(text) == expected


@pytest.mark.parametrize("text", ["", "a:b", "1:2:3:4", "1.5:3", "0:10:0", "0:10:-1", "-", "1,2"])
def test_frame_slice_syntax_errors(text):
    import argparse

    with pytest.raises(argparse.ArgumentTypeError):
        parse_frame_slice(text)


def test_select_frames_is_a_slice_over_frame_numbers():
    frames = range(3, 11)  # a cache starting at frame 3
    assert preview.select_frames(None, frames) == list(frames)
    assert preview.select_frames(slice(4, 9, 2), frames) == [4, 6, 8]
    assert preview.select_frames(slice(None, 5, None), frames) == [3, 4]
    assert preview.select_frames(slice(8, None, None), frames) == [8, 9, 10]
    assert preview.select_frames(slice(10, 11, None), frames) == [10]


@pytest.mark.parametrize("frames, words", [
    (slice(0, 5, None), "frame 0 is not in the cache"), (slice(11, None, None), "frame 11 is not in the cache"),
    (slice(3, 12, None), "the end 12 is past the last frame"), (slice(5, 5, None), "selects no frame"),
])
def test_select_frames_errors_name_the_option_and_the_range(frames, words):
    with pytest.raises(preview.PreviewError) as err:
        preview.select_frames(frames, range(3, 11), "c.usdc")
    assert str(err.value).startswith("--frames: ") and words in str(err.value)
    assert "c.usdc holds frames 3 to 10" in str(err.value)


def test_evenly_spaced_keeps_both_ends():
    assert preview.evenly_spaced(range(0, 121), 4) == [0, 40, 80, 120]
    assert preview.evenly_spaced([2, 5], 4) == [2, 5]


def test_size_syntax():
    import argparse

    assert parse_size("640x480") == (640, 480)
    for bad in ("640", "640x", "x480", "640*480", "8x8", "640x99999"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_size(bad)


# ------------------------------------------------------------------------------------ command line


def preview_rc(capsys, *args) -> tuple[int, str]:
    rc = main(["preview", *map(str, args)])
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1  # one message, no traceback
    return rc, err


def test_bad_inputs_exit_2_with_one_message_naming_the_file(cache, tmp_path, capsys):
    out = tmp_path / "p.png"
    rc, err = preview_rc(capsys, tmp_path / "missing.usdc", "-o", out)
    assert rc == 2 and "missing.usdc: no such file" in err

    text = tmp_path / "notes.usda"
    text.write_text("this is not USD\n")
    rc, err = preview_rc(capsys, text, "-o", out)
    assert rc == 2 and "notes.usda: not a USD file" in err and "stage.cpp" not in err

    empty = tmp_path / "empty.usda"
    stage = Usd.Stage.CreateNew(str(empty))
    stage.DefinePrim("/World", "Xform")
    stage.Save()
    del stage
    rc, err = preview_rc(capsys, empty, "-o", out)
    assert rc == 2 and "empty.usda: no cloth in the cache" in err

    rc, err = preview_rc(capsys, cache, "-o", tmp_path / "p.jpg")
    assert rc == 2 and "p.jpg: the preview must be a .png" in err

    rc, err = preview_rc(capsys, cache, "-o", out, "--frames", "0:99")
    assert rc == 2 and "--frames: the end 99" in err and "cache.usdc holds frames 0 to 6" in err
    assert not out.exists() and not (tmp_path / "p.jpg").exists()


def test_bad_option_syntax_is_an_argparse_error_naming_the_option(cache, capsys):
    for option, value in (("--frames", "x:y"), ("--size", "big")):
        with pytest.raises(SystemExit) as exit_:
            main(["preview", str(cache), "-o", str(cache.parent / "p.png"), option, value])
        assert exit_.value.code == 2
        assert f"argument {option}:" in capsys.readouterr().err


def test_unwritable_output_exits_1_and_names_the_file(cache, tmp_path, capsys, monkeypatch):
    rc, err = preview_rc(capsys, cache, "-o", tmp_path / "no" / "dir" / "p.png")
    assert rc == 1 and "cannot write preview" in err and "p.png" in err and "does not exist" in err
    rc, err = preview_rc(capsys, cache, "-o", cache / "p.png")  # the "directory" is the cache file
    assert rc == 1 and "p.png" in err and "is not a directory" in err
    # Permissions cannot be tested by chmod when the tests run as root, so ask the check itself.
    monkeypatch.setattr(preview.os, "access", lambda path, mode: False)
    rc, err = preview_rc(capsys, cache, "-o", tmp_path / "p.png")
    assert rc == 1 and "p.png" in err and "is not writable" in err
    assert not (tmp_path / "p.png").exists()


@pytest.mark.slow
def test_a_failed_write_leaves_no_partial_file(cache, tmp_path, capsys, monkeypatch):
    def fail_halfway(self, fp, *args, **kwargs):
        with open(fp, "wb") as f:
            f.write(b"\x89PNG half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", fail_halfway)
    out = tmp_path / "p.png"
    rc, err = preview_rc(capsys, cache, "-o", out)
    assert rc == 1 and "cannot write preview" in err and "No space left on device" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache.usdc"]


def test_an_existing_preview_is_replaced_whole(cache, tmp_path, capsys):
    out = tmp_path / "p.png"
    out.write_bytes(b"old")
    assert main(["preview", str(cache), "-o", str(out), "--size", "64x64"]) == 0
    assert Image.open(out).size == (64, 64)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache.usdc", "p.png"]


RUN_SCENE = """
[simulation]
fps = 30
frames = 3
substeps = 1
iterations = 2

[output]
path = "tiny.usdc"

[[cloth]]
name = "sheet"
resolution = [4, 5]
size = [0.3, 0.4]
origin = [0.0, 1.0, 0.0]
pins = ["top-left", "top-right"]
"""


@pytest.mark.slow
def test_run_with_preview_writes_a_png_next_to_the_cache(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny.toml").write_text(RUN_SCENE)
    assert main(["run", "tiny.toml", "--device", "cpu", "-q", "--preview"]) == 0
    out = capsys.readouterr().out
    png = tmp_path / "tiny.png"
    assert png.is_file() and "preview" in out and str(png.relative_to(tmp_path)) in out
    assert Image.open(png).size == preview.DEFAULT_SIZE[".png"] and load_rgb(png).std() > 20


def test_without_the_flag_run_writes_no_preview(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny.toml").write_text(RUN_SCENE)
    assert main(["run", "tiny.toml", "--device", "cpu", "-q"]) == 0
    assert not (tmp_path / "tiny.png").exists() and "preview" not in capsys.readouterr().out


# ------------------------------------------------------------------------------------------ imports


@pytest.mark.slow
def test_preview_needs_no_simulator_and_leaves_pyplot_alone(cache):
    probe = (
        "import sys; from warp_verlet.apps.cli import main; "
        "rc = main(['preview', 'cache.usdc', '-o', 'probe.png', '--size', '64x64']); "
        "print(rc, *(m in sys.modules for m in ('warp', 'matplotlib.pyplot')))"
    )
    out = subprocess.run([sys.executable, "-c", probe], cwd=cache.parent, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-3:] == ["0", "False", "False"]


def test_validate_imports_no_renderer(tmp_path):
    (tmp_path / "tiny.toml").write_text(RUN_SCENE)
    probe = (
        "import sys; from warp_verlet.apps.cli import main; rc = main(['validate', 'tiny.toml']); "
        "print(rc, *(m in sys.modules for m in ('warp', 'pxr', 'matplotlib', 'mitsuba')))"
    )
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.split()[-5:] == ["0", "False", "False", "False", "False"]


# ------------------------------------------------------------------------------ damaged caches, big GIFs


def damage_frame(path, frame: int, how: str) -> None:
    """Overwrite frame ``frame``'s points in a crate file: with NaN ("nan"), or give their array an impossible
    length ("count"), as a bad sector or a torn copy would."""
    cache = preview.open_cache(path)
    points = np.asarray(cache.cloths[0].prim.GetPointsAttr().Get(frame), np.float32).tobytes()
    del cache
    data = bytearray(path.read_bytes())
    at = data.find(points)
    assert at > 0 and data.find(points, at + 1) < 0  # the frame's points, stored once
    if how == "nan":
        data[at:at + 24] = b"\xff" * 24
    else:
        data[at - 8:at] = (10**6).to_bytes(8, "little")  # the array's element count
    path.write_bytes(bytes(data))


@pytest.mark.slow
@pytest.mark.parametrize("how, words", [("nan", "holds non-finite values"), ("count", "USD cannot read")])
def test_a_damaged_frame_is_one_clear_error(tmp_path, how, words):
    path = write_cache(tmp_path / "damaged.usdc", rows=5, cols=5)
    damage_frame(path, 2, how)  # a frame both images draw (a PNG shows 0, 2, 4 and 6)
    for out in ("d.png", "d.gif"):
        done = subprocess.run([sys.executable, "-m", "warp_verlet", "preview", str(path), "-o", str(tmp_path / out)],
                              capture_output=True, text=True)
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in done.stderr and ".cpp" not in done.stderr
        assert lines[0].startswith(f"error: {path}: frame 2 is damaged: ") and words in lines[0]
        assert not (tmp_path / out).exists()
    # The frames around it are still fine.
    assert main(["preview", str(path), "-o", str(tmp_path / "ok.png"), "--frames", "3:7"]) == 0


def test_a_gif_is_written_one_frame_at_a_time(cache, monkeypatch):
    # An animation held whole until the end would be 24 GB at 120 frames of 8192 x 8192. Now each
    # frame is on disk before the next is drawn.
    sizes = []
    real = preview._draw_panels
    out = cache.parent / "s.gif"

    def spy(*args):
        partials = list(cache.parent.glob(".s.*.partial.gif"))
        sizes.append(partials[0].stat().st_size if partials else 0)
        return real(*args)

    monkeypatch.setattr(preview, "_draw_panels", spy)
    assert main(["preview", str(cache), "-o", str(out), "--size", "64x64"]) == 0
    assert len(sizes) == FRAMES + 1
    assert sizes[0] == 0 and all(b > a for a, b in zip(sizes, sizes[1:]))
    image = Image.open(out)
    assert image.n_frames == FRAMES + 1 and image.info.get("loop") == 0 and image.info.get("duration") == 30  # 1/30 s, in whole 1/100 s


def test_a_size_that_cannot_be_held_is_refused_before_drawing(cache, monkeypatch, capsys):
    monkeypatch.setattr(preview, "available_host_bytes", lambda: 200 * 10**6)
    assert main(["preview", str(cache), "-o", str(cache.parent / "big.gif"), "--size", "8192x8192"]) == 2
    err = capsys.readouterr().err
    need = 8192 * 8192 * preview.BYTES_PER_PIXEL / 1e9
    assert f"--size 8192x8192: drawing one image of that size needs about {need:.2g} GB" in err and "0.2 GB" in err
    assert not (cache.parent / "big.gif").exists()
    assert main(["preview", str(cache), "-o", str(cache.parent / "small.gif"), "--size", "64x64"]) == 0
