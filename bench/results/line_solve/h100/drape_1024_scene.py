"""scenes/drape_1024.toml with its shear and bend, substeps, sweeps and line passes set per row; the stretch every
15 frames and the mean RMS over frames 45-90. DRAPE_GRID=2048 runs the same drape at 2048 x 2048."""
import copy, os, sys, time, tomllib
sys.path.insert(0, ".")
import numpy as np, warp as wp
wp.config.quiet = True
from warp_verlet.input.scene import parse_scene
from warp_verlet.core.simulator import Simulator
base = tomllib.load(open("scenes/drape_1024.toml", "rb"))
base.pop("output", None)
if os.environ.get("DRAPE_GRID"):  # the same drape at another grid, DRAPE_GRID particles a side
    base["cloth"][0]["resolution"] = [int(os.environ["DRAPE_GRID"])] * 2
print("| S x K | compliance shear/bend | line passes | sticks | positions | ms/frame | RMS | max | mean RMS 45-90 | "
      "frame: RMS%/max% |")
print("|---|---|---|---|---|---|---|---|---|---|")
# Each row: substeps, sweeps, line passes, the shear and bend compliance (m/N; "rigid": none) and, optionally,
# the sticks' form (Simulator's sticks, default "auto"). Rows given as arguments ("128,1,1,1.0" or
# "256,1,1,1.0,tiled" ...) replace these.
ROWS = [(64, 2, 0, 1.0, "auto"), (64, 1, 1, 1.0, "auto"), (32, 2, 1, 1.0, "auto"), (64, 2, 0, None, "auto")]
if len(sys.argv) > 1:
    ROWS = [(int(f[0]), int(f[1]), int(f[2]), None if f[3] == "rigid" else float(f[3]), f[4] if len(f) > 4 else "auto")
            for f in (arg.split(",") for arg in sys.argv[1:])]
for S, K, lines, soft, form in ROWS:
    t = copy.deepcopy(base)
    t["simulation"].update(substeps=S, iterations=K)
    if soft:
        t["cloth"][0]["compliance"] = {"shear": soft, "bend": soft}
    else:
        t["cloth"][0].pop("compliance", None)  # all three families rigid
    t["cloth"][0]["line_passes"] = lines
    sim = Simulator(parse_scene(t, file="scenes/drape_1024.toml"), "cuda", sticks=form)
    timed, hist, means = 0.0, [], []
    for f in range(90):
        wp.synchronize(); t0 = time.perf_counter(); sim.step_frame(); wp.synchronize()
        if f >= 2:
            timed += time.perf_counter() - t0
        if f % 15 == 14:
            s = sim.stretch(); hist.append(f"{f+1}:{100*s.rms:.2f}/{100*s.max:.1f}")
            if f >= 44:
                means.append(s.rms)
    s = sim.stretch()
    print(f"| {S} x {K} | {soft} | {lines} | {sim.model.sticks_form} | {sim.model.precision} | {timed/88*1e3:.2f} | {100*s.rms:.3f}% | {100*s.max:.2f}% | {100*np.mean(means):.2f}% | {' '.join(hist)} |", flush=True)
    sim.close()
