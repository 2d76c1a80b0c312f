"""bench.self_contact's folded drop with the candidate search's constants set otherwise: QUERY_REACH (pairs
within this x their thickness are candidates for a substep), GRID_CELL (the hash grid's cell, x the query
radius) and, optionally third, CELLS_PER_PARTICLE (the hash grid's cells at most per colliding particle); each
set of values a row of ms/frame, worst penetration and approach, in one process, after a row without
self-collision (--no-off leaves it out).

    PYTHONPATH=. python bench/results/self_contact_params/params.py --sizes 128 --substeps 8 \
        --pairs 1.25,2 1.1,2 1.0,2 1.25,1 1.25,1.5
    PYTHONPATH=. python bench/results/self_contact_params/params.py --device cuda --sizes 1024 --substeps 32 \
        --iterations 1 --frames 20 --stride 3 --pairs 1.25,2 1.1,2 1.25,1 1.25,1.5 1.25,2,2
"""
import argparse
import json
import os
from pathlib import Path

import warp_verlet.constraints.self_contact as self_contact
from bench import self_contact as bench
from bench.common import quiet_warp

parser = argparse.ArgumentParser()
parser.add_argument("--sizes", type=int, nargs="+", default=[128])
parser.add_argument("--substeps", type=int, default=8)
parser.add_argument("--iterations", type=int, default=8)
parser.add_argument("--frames", type=int, default=60)
parser.add_argument("--stride", type=int, default=1)
parser.add_argument("--device", default="cpu")
parser.add_argument("--pairs", nargs="+", default=["1.25,2"], help="QUERY_REACH,GRID_CELL[,CELLS_PER_PARTICLE]")
parser.add_argument("--no-off", action="store_true", help="no row without self-collision")
args = parser.parse_args()
quiet_warp()
rows = []
columns = ("n", "stride", "thickness mm", "ms/frame", "worst penetration", "approach")
defaults = (self_contact.QUERY_REACH, self_contact.GRID_CELL, self_contact.CELLS_PER_PARTICLE)
for n in args.sizes:
    if not args.no_off:
        row = bench.run(n, False, args.frames, args.substeps, args.iterations, args.device)
        rows.append({"self_collision": "off", **{k: row[k] for k in columns}})
        print(rows[-1], flush=True)
    for pair in args.pairs:
        values = [float(v) for v in pair.split(",")]
        reach, cell, cells = values + list(defaults[len(values):])
        self_contact.QUERY_REACH, self_contact.GRID_CELL, self_contact.CELLS_PER_PARTICLE = reach, cell, int(cells)
        row = bench.run(n, True, args.frames, args.substeps, args.iterations, args.device, args.stride)
        row = {"reach": reach, "cell": cell, "cells/particle": int(cells), **{k: row[k] for k in columns}}
        rows.append(row)
        print(row, flush=True)
Path(os.environ.get("OUT", "/tmp"), "params.json").write_text(json.dumps(rows, indent=1))
