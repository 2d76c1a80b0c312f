"""bench.self_contact's folded drop with the candidate search's two constants set otherwise: QUERY_REACH (pairs
within this x their thickness are candidates for a substep) and GRID_CELL (the hash grid's cell, x the query
radius); each pair of values a row of ms/frame, worst penetration and approach, in one process.

    PYTHONPATH=. python bench/results/self_contact_params/params.py --sizes 128 --substeps 8 \
        --pairs 1.25,2 1.1,2 1.0,2 1.25,1 1.25,1.5
    PYTHONPATH=. python bench/results/self_contact_params/params.py --device cuda --sizes 1024 --substeps 32 \
        --iterations 1 --frames 20 --stride 3 --pairs 1.25,2 1.1,2 1.25,1 1.25,1.5
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
parser.add_argument("--pairs", nargs="+", default=["1.25,2"], help="QUERY_REACH,GRID_CELL")
args = parser.parse_args()
quiet_warp()
rows = []
for n in args.sizes:
    for pair in args.pairs:
        reach, cell = (float(v) for v in pair.split(","))
        self_contact.QUERY_REACH, self_contact.GRID_CELL = reach, cell
        row = bench.run(n, True, args.frames, args.substeps, args.iterations, args.device, args.stride)
        row = {"reach": reach, "cell": cell, **{k: row[k] for k in ("n", "stride", "thickness mm", "ms/frame",
                                                                    "worst penetration", "approach")}}
        rows.append(row)
        print(row, flush=True)
Path(os.environ.get("OUT", "/tmp"), "params.json").write_text(json.dumps(rows, indent=1))
