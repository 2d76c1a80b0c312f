"""Renderers for `warp-verlet preview`, measured: seconds per frame at 64^2, 256^2 and 1024^2 grids, and the
same panel rendered by Blender for an image comparison.

Each mode runs in the Python that has its renderer:

    python bench/preview_renderers.py time [--old-source DIR] [--out bench/results/preview/renderers.md]
        the project's preview (Mitsuba 3, scalar_rgb), and, given DIR (an export of the project from before the
        change), the matplotlib/mplot3d preview it replaced, on the same synthetic drape
    python bench/preview_renderers.py time-pyvista          (a Python with pyvista: VTK off-screen)
    python bench/preview_renderers.py export CACHE FRAME OUT.npz [--size WxH]
        the panel the preview draws of one frame (its triangles, spheres, planes, camera), for Blender
    python bench/preview_renderers.py blender IN.npz OUT.png [--engine workbench|cycles] [--samples N]
        (run with a Python that has bpy) the same panel rendered by Blender, camera and key light matched

The synthetic drape: a square cloth of n x n quads hanging over a sphere (a closed-form surface, so no
simulation is needed), with the sphere and a ground plane, in one 800 x 800 panel and one 400 x 400 panel.
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import sys
import time
from pathlib import Path

import numpy as np

GRIDS = (64, 256, 1024)
SIZES = ((400, 400), (800, 800))
REPEATS = 3


def drape_points(n: int) -> np.ndarray:
    """(n + 1)^2 points of a 1.6 m square cloth draped over a 0.35 m ball centred 0.35 m above the ground."""
    r, c = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    x, z = 1.6 * (c / n - 0.5), 1.6 * (r / n - 0.5)
    radial = np.hypot(x, z)
    y = np.where(radial < 0.36, 0.35 + np.sqrt(np.maximum(0.36**2 - radial**2, 0)),
                 np.maximum(0.71 - 1.1 * (radial - 0.36), 0.005))
    y = y + 0.02 * np.sin(9 * np.arctan2(z, x)) * np.clip(radial - 0.36, 0, None)  # folds
    return np.stack([x, y, z], -1).reshape(-1, 3)


def drape_geometry(n: int):
    from warp_verlet.output.cache_reader import ClothFrame, ClothPrim, FrameGeometry
    from warp_verlet.geometry.faces import grid_faces

    faces = grid_faces(n + 1, n + 1)
    prim = ClothPrim(prim=None, faces=faces, grid=(n + 1, n + 1), points_needed=(n + 1) ** 2)
    cloth = ClothFrame(prim, drape_points(n), np.zeros(0, np.int64), (n + 1, n + 1))
    ground = np.array([[-50.0, 0, -50], [50, 0, -50], [50, 0, 50], [-50, 0, 50]])
    # The old preview's FrameGeometry also held the decimated polygons (``cloths``), which its caller fills in.
    old = {"cloths": ()} if "cloths" in {f.name for f in dataclasses.fields(FrameGeometry)} else {}
    return FrameGeometry(frame=0, seconds=0.0, ropes=(), spheres=((np.array([0.0, 0.35, 0.0]), 0.35),),
                         planes=(ground,), cloth_frames=(cloth,), **old)


def best_of(fn, repeats: int = REPEATS) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def time_mitsuba() -> dict:
    from warp_verlet.apps import preview_render

    preview_render.render_frame(drape_geometry(8), "Y", 64, 64)  # loads the renderer's library once
    out = {}
    for n in GRIDS:
        geometry = drape_geometry(n)
        for w, h in SIZES:
            out[(n, w)] = best_of(lambda: preview_render.render_frame(geometry, "Y", w, h))
            print(f"mitsuba {n}^2 {w}x{h}: {out[(n, w)]:.3f} s", flush=True)
    return out


def time_old_matplotlib(source: Path) -> dict:
    """The preview before this change (matplotlib's mplot3d, decimated to 64 x 64 quads), from an export of it."""
    sys.path.insert(0, str(source))
    for name in [m for m in sys.modules if m == "warp_verlet" or m.startswith("warp_verlet.")]:
        del sys.modules[name]
    # The old tree's layout (a flat package), imported from ``source``.
    from warp_verlet import preview as old  # the old module
    from warp_verlet.cache_reader import visible_polygons

    out = {}
    for n in GRIDS:
        geometry = drape_geometry(n)
        cloth = geometry.cloth_frames[0]
        decimated = visible_polygons(cloth.points, cloth.cloth.faces, (), cloth.grid)
        geometry = type(geometry)(**{**geometry.__dict__, "cloths": (decimated,)})
        for w, h in SIZES:
            def draw():
                view, planes = old.fit_view([geometry], "Y")
                fig = old._figure((w, h))
                old._draw_panels(fig, type("C", (), {"path": Path("drape.usdc")})(), [geometry], planes, view)
                fig.canvas.draw()
            out[(n, w)] = best_of(draw)
            print(f"matplotlib {n}^2 {w}x{h}: {out[(n, w)]:.3f} s", flush=True)
    sys.path.remove(str(source))
    return out


def time_pyvista() -> None:
    import pyvista as pv

    for n in GRIDS:
        points = drape_points(n)
        r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        a = (r * (n + 1) + c).ravel()
        faces = np.stack([np.full_like(a, 4), a, a + n + 1, a + n + 2, a + 1], 1).ravel()
        for w, h in SIZES:
            def draw():
                plotter = pv.Plotter(off_screen=True, window_size=(w, h))
                plotter.add_mesh(pv.PolyData(points, faces), color=(0.8, 0.33, 0.24), smooth_shading=True)
                plotter.add_mesh(pv.Sphere(radius=0.35, center=(0, 0.35, 0)))
                plotter.screenshot(return_img=True)
                plotter.close()
            print(f"pyvista {n}^2 {w}x{h}: {best_of(draw):.3f} s", flush=True)


def write_table(path: Path, results: dict[str, dict]) -> None:
    lines = [
        "# Preview renderers: seconds per frame",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {__import__('os').cpu_count()} CPU cores shared "
        "with other work, no GPU. Best of 3, one panel of the synthetic drape (cloth, sphere, ground); the time "
        "includes building the renderer's scene from numpy. `python bench/preview_renderers.py time`.",
        "",
        "| renderer | " + " | ".join(f"{n}² at {w}²" for n in GRIDS for w, _ in SIZES) + " |",
        "|---|" + "---|" * (len(GRIDS) * len(SIZES)),
    ]
    for name, times in results.items():
        lines.append(f"| {name} | " + " | ".join(f"{times[(n, w)]:.2f}" for n in GRIDS for w, _ in SIZES) + " |")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")


# ------------------------------------------------------------------------------------------------ Blender


def export_panel(cache: Path, frame: int, out: Path, size: tuple[int, int]) -> None:
    from warp_verlet.apps import preview_render
    from warp_verlet.output.cache_reader import open_cache, read_frame

    opened = open_cache(cache)
    geometry = read_frame(opened, frame)
    panel = preview_render.frame_panel(geometry, opened.up_axis, *size)
    # Blender draws every face: the full cloth, not the preview's grid at the panel's density.
    full = [preview_render.cloth_mesh(c, 1 << 30) for c in geometry.cloth_frames]
    arrays = {"size": np.array(size), "towards_light": preview_render.light_direction(opened.up_axis)}
    for key in ("centre", "towards_eye", "right", "up"):
        arrays[f"camera_{key}"] = getattr(panel.camera, key)
    arrays["camera_scalars"] = np.array([panel.camera.half_width, panel.camera.half_height, panel.camera.distance])
    for i, mesh in enumerate(full):
        arrays[f"cloth{i}_points"], arrays[f"cloth{i}_triangles"] = mesh.points, mesh.triangles
        arrays[f"cloth{i}_colour"] = preview_render.srgb_to_linear(
            preview_render.CLOTH_COLOURS[i % len(preview_render.CLOTH_COLOURS)])
    for i, mesh in enumerate(panel.ropes):
        arrays[f"rope{i}_points"], arrays[f"rope{i}_triangles"] = mesh.points, mesh.triangles
    arrays["spheres"] = np.array([[*c, r] for c, r in panel.spheres]).reshape(-1, 4)
    arrays["planes"] = np.array(panel.planes).reshape(-1, 4, 3)
    arrays["colours"] = preview_render.srgb_to_linear(
        [preview_render.ROPE_COLOUR, preview_render.SPHERE_COLOUR, preview_render.PLANE_COLOUR])
    arrays["light"] = np.array([preview_render.KEY_LIGHT, preview_render.FILL_LIGHT])
    np.savez(out, **arrays)
    print(f"wrote {out}")


def render_blender(npz: Path, out: Path, engine: str, samples: int) -> None:
    import bpy
    from mathutils import Matrix

    data = np.load(npz)
    out = out.resolve()  # Blender reads a relative path as relative to the .blend file
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    width, height = (int(x) for x in data["size"])
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"  # plain sRGB, as the preview writes
    key, fill = (float(x) for x in data["light"])

    def material(name, rgb):
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = (*[float(x) for x in rgb], 1.0)
        bsdf.inputs["Roughness"].default_value = 1.0
        for specular in ("Specular IOR Level", "Specular"):
            if specular in bsdf.inputs:
                bsdf.inputs[specular].default_value = 0.0
        mat.diffuse_color = (*[float(x) for x in rgb], 1.0)  # what Workbench's material colour shows
        return mat

    def add_mesh(name, points, triangles, mat, smooth):
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata(points.tolist(), [], triangles.tolist())
        mesh.update()
        for polygon in mesh.polygons:
            polygon.use_smooth = smooth
        obj = bpy.data.objects.new(name, mesh)
        obj.data.materials.append(mat)
        scene.collection.objects.link(obj)

    rope_rgb, sphere_rgb, plane_rgb = data["colours"]
    i = 0
    while f"cloth{i}_points" in data:
        add_mesh(f"cloth{i}", data[f"cloth{i}_points"], data[f"cloth{i}_triangles"],
                 material(f"cloth{i}", data[f"cloth{i}_colour"]), True)
        i += 1
    i = 0
    while f"rope{i}_points" in data:
        add_mesh(f"rope{i}", data[f"rope{i}_points"], data[f"rope{i}_triangles"], material("rope", rope_rgb), True)
        i += 1
    for k, (x, y, z, r) in enumerate(data["spheres"]):
        bpy.ops.mesh.primitive_uv_sphere_add(segments=96, ring_count=48, radius=float(r), location=(x, y, z))
        bpy.context.object.data.materials.append(material(f"sphere{k}", sphere_rgb))
        bpy.ops.object.shade_smooth()
    for k, quad in enumerate(data["planes"]):
        add_mesh(f"plane{k}", quad, np.array([[0, 1, 2], [0, 2, 3]]), material("plane", plane_rgb), False)

    centre, towards_eye = data["camera_centre"], data["camera_towards_eye"]
    right, up = data["camera_right"], data["camera_up"]
    half_width, _, distance = (float(x) for x in data["camera_scalars"])
    camera_data = bpy.data.cameras.new("camera")
    camera_data.type = "ORTHO"
    camera_data.sensor_fit = "HORIZONTAL"
    camera_data.ortho_scale = 2 * half_width  # the image's width in stage units
    camera_data.clip_start, camera_data.clip_end = 1e-3 * distance, 4 * distance
    camera = bpy.data.objects.new("camera", camera_data)
    eye = centre + distance * towards_eye
    rotation = np.stack([right, up, towards_eye], axis=1)  # Blender's camera looks down its -Z, +Y up
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = rotation, eye
    camera.matrix_world = Matrix(matrix.tolist())
    scene.collection.objects.link(camera)
    scene.camera = camera

    def sun(name, towards_light, share, shadows):
        light = bpy.data.lights.new(name, "SUN")
        light.energy = share * np.pi  # irradiance; a diffuse surface facing it returns albedo * energy / pi
        light.angle = 0.0
        light.use_shadow = shadows
        obj = bpy.data.objects.new(name, light)
        z = towards_light / np.linalg.norm(towards_light)  # a sun shines down its -Z
        x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        matrix = np.eye(4)
        matrix[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        obj.matrix_world = Matrix(matrix.tolist())
        scene.collection.objects.link(obj)

    sun("key", data["towards_light"], key, True)
    sun("fill", towards_eye, fill, False)  # from the camera: it lights what the camera sees
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    scene.world = world
    if engine == "cycles":
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.max_bounces = 0  # direct light only, as the preview has
        # The white background the preview has, seen by the camera only.
        scene.render.film_transparent = True
    else:
        scene.render.engine = "BLENDER_WORKBENCH"
        shading = scene.display.shading
        shading.light, shading.color_type = "STUDIO", "MATERIAL"
        shading.show_shadows = True
        shading.show_cavity = False
        scene.render.film_transparent = True
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.filepath = str(out.with_suffix(".rgba.png"))
    start = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    print(f"blender {engine}: {time.perf_counter() - start:.1f} s", flush=True)
    from PIL import Image

    rgba = Image.open(out.with_suffix(".rgba.png")).convert("RGBA")
    white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
    Image.alpha_composite(white, rgba).convert("RGB").save(out)
    out.with_suffix(".rgba.png").unlink()
    print(f"wrote {out}")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="mode", required=True)
    t = sub.add_parser("time")
    t.add_argument("--old-source", type=Path)
    t.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "preview" / "renderers.md")
    sub.add_parser("time-pyvista")
    e = sub.add_parser("export")
    e.add_argument("cache", type=Path)
    e.add_argument("frame", type=int)
    e.add_argument("out", type=Path)
    e.add_argument("--size", default="800x800")
    b = sub.add_parser("blender")
    b.add_argument("npz", type=Path)
    b.add_argument("out", type=Path)
    b.add_argument("--engine", choices=("workbench", "cycles"), default="cycles")
    b.add_argument("--samples", type=int, default=64)
    args = parser.parse_args(argv)
    if args.mode == "time":
        results = {"Mitsuba 3 scalar_rgb (this preview, every grid cell up to the panel's pixels)": time_mitsuba()}
        if args.old_source:
            results["matplotlib mplot3d (the previous preview, 64 x 64 quads)"] = time_old_matplotlib(args.old_source)
        write_table(args.out, results)
    elif args.mode == "time-pyvista":
        time_pyvista()
    elif args.mode == "export":
        w, h = (int(x) for x in args.size.split("x"))
        export_panel(args.cache, args.frame, args.out, (w, h))
    else:
        render_blender(args.npz, args.out, args.engine, args.samples)


if __name__ == "__main__":
    main()
