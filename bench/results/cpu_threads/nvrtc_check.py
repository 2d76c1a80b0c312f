"""Compiles the kernels that gained a `first` particle (the colliders' clamps, the self-contact search) for sm_90
with NVRTC, float32 and float64 positions, on a machine without a GPU:

    PYTHONPATH=. python bench/results/cpu_threads/nvrtc_check.py
"""
import os
import warp as wp
wp.config.quiet = True
wp.init()
import warp._src.context as c, warp._src.build as b
from warp_verlet.kernels import collide_plane, collide_sphere, collide_mesh, self_contact
from warp_verlet.kernels.positions import instance
os.makedirs("/tmp/nv", exist_ok=True)
for mod, names in ((collide_plane, ["collide_planes"]), (collide_sphere, ["collide_spheres"]),
                   (collide_mesh, ["collide_meshes", "collide_moving_meshes"]), (self_contact, ["contact_candidates"])):
    for name in names:
        for vec in (wp.vec3, wp.vec3d):
            k = instance(getattr(mod, name), vec)
            m = k.module
            src = c.ModuleBuilder(m, m.options).codegen("cuda")
            open("/tmp/nv/k.cu", "w").write(src)
            b.build_cuda("/tmp/nv/k.cu", 90, "/tmp/nv/k.ptx", pch_dir="/tmp/nv/pch", use_precompiled_headers=False)
            print(name, vec.__name__, "compiled for sm_90")
