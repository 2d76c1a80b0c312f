"""Prototype (dropped): bench.implicit_grid with the longest sticks first (BENDFIRST=1); TILE_SHIFT as in
tiled_inner.py."""
import os, sys
from warp_verlet.geometry import topology
if os.environ.get("BENDFIRST"):
    topology.SWEEP_ORDER = (topology.BEND_H, topology.BEND_V, topology.SHEAR_DIAG, topology.SHEAR_ANTI, topology.STRUCT_H, topology.STRUCT_V)
from bench import implicit_grid
sys.exit(implicit_grid.main(sys.argv[1:]))
