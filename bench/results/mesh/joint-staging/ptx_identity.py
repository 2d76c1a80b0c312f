"""Whether the landed clustered kernel (kernels/stick_clusters.py) compiles to the same PTX as the kernels measured
on the GPU: its rigid form as commit 88a8c52's kernel (staged one kind after another), its staged-soft form as the
one-batch kernel of the lease's last run (h100/final.txt), rebuilt from 88a8c52's by prototype/hold_region.diff.
NVRTC compiles for sm_90 without a GPU; the PTX is compared after the module names are taken out. Comments and
source lines aside, the landed kernel only rearranges the measured ones' static branches.

    PYTHONPATH=. python bench/results/mesh/joint-staging/ptx_identity.py
"""
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import warp as wp

wp.config.quiet = True
wp.init()
import warp._src.context as context  # noqa: E402
import warp._src.build as build  # noqa: E402

here = Path(__file__).resolve().parent
work = Path(tempfile.mkdtemp())
base = subprocess.run(["git", "show", "88a8c52:kernels/stick_clusters.py"], capture_output=True, text=True,
                      check=True).stdout
for module in ("grid_tiles", "positions", "relax"):
    base = base.replace(f"from .{module}", f"from warp_verlet.kernels.{module}")
(work / "base_clusters.py").write_text(base)
subprocess.run(["patch", "-s", "-o", str(work / "hold_region.py"), str(work / "base_clusters.py"),
                str(here / "prototype" / "hold_region.diff")], check=True)
sys.path[:0] = [str(work)]
import base_clusters  # noqa: E402
import hold_region  # noqa: E402
from warp_verlet.kernels import stick_clusters as landed  # noqa: E402


def ptx(make, soft: bool, name: str) -> str:
    kernel = make(352, 1536, 12, soft, stage_soft=True, block_dim=256)  # the 1024^2 triangle mesh's capacities
    module = kernel.module
    cu = work / f"{name}.cu"  # names of one length: the PTX mangles the file name with its length
    cu.write_text(context.ModuleBuilder(module, module.options).codegen("cuda"))
    out = work / f"{name}.ptx"
    build.build_cuda(str(cu), 90, str(out), pch_dir=str(work / "pch"), fast_math=module.options.get("fast_math", False),
                     use_precompiled_headers=False)
    text = out.read_text(errors="replace")
    text = re.sub(r"relax_stick_clusters_[0-9a-f]+", "K", text)
    text = re.sub(r"_INTERNAL_[0-9]+_[0-9]+_[a-z0-9]+_cu_[0-9a-f]+", "I", text)
    return "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//"))


for soft, measured in ((False, base_clusters), (True, hold_region)):
    same = ptx(measured.relax_stick_clusters, soft, f"m{int(soft)}") == ptx(landed.relax_stick_clusters, soft,
                                                                                   f"l{int(soft)}")
    print(f"{'soft, staged' if soft else 'rigid'}: landed PTX {'identical to' if same else 'DIFFERS from'} the "
          f"measured kernel's ({'prototype/hold_region.diff' if soft else 'commit 88a8c52'})")
