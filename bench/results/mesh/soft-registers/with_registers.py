"""bench.mesh_throughput with the clustered sweep's soft sticks held in registers (soft_registers=True), for a
comparison in one lease before it was the default: PYTHONPATH=. python bench/results/mesh/soft-registers/with_registers.py ARGS."""
import runpy
import sys

import warp_verlet.kernels.stick_clusters as kernels

landed = kernels.relax_stick_clusters


def held_in_registers(*args, **kwargs):
    return landed(*args, **{**kwargs, "stage_soft": False, "soft_registers": True})


kernels.relax_stick_clusters = held_in_registers
sys.argv = ["bench.mesh_throughput", *sys.argv[1:]]
runpy.run_module("bench.mesh_throughput", run_name="__main__")
