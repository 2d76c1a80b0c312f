"""Kernel times of the folded drop at 1024^2, 32x1, with a self-collision stride."""
import sys
import warp as wp
from warp_verlet.core.simulator import Simulator
from warp_verlet.constraints.self_contact import DEFAULT_FRACTION
from bench.self_contact import SIZE, folded, folded_scene
from bench.kernel_times import frame_times, print_times
from bench.common import quiet_warp
quiet_warp()
size = int(sys.argv[1]); stride = int(sys.argv[2])
sim = Simulator(folded_scene(size, True, 20, 32, 1, stride), "cuda", use_graph=False)
spacing = SIZE / (size - 1)
sim.state.set_positions(folded(sim.model.rest_positions, spacing, DEFAULT_FRACTION * spacing * stride))
times, _ = frame_times(sim, 14, wp.TIMING_ALL)
print_times(f"{size}^2 folded_drop stride {stride} 32x1 frame 15", times)
