"""Stick arrays swept cluster by cluster in shared memory (kernels/stick_clusters.py): what the tiled sweep is to a
grid, for any cloth whose sticks are arrays (a mesh, or several cloths).

A sweep of stick arrays is otherwise one launch per colour, and each launch streams its sticks' ends, rest lengths
and both ends' positions through memory; a graph colour of a mesh scatters its sticks over the cloth, so a
launch also reads positions out of order. Here the particles are cut into clusters of about
``CLUSTER_PARTICLES`` consecutive particles in Morton order of their rest positions (a compact patch of cloth),
each cluster owns the sticks whose first particle it holds, and a block projects every colour of its cluster's
sticks on positions held in shared memory: a sweep reads and writes each position about once, in a few launches
(one per cluster colour, or on a large mesh one launch, chained) instead of one per stick colour.

Everything here is host-side numpy, built once per model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kind import ConstraintSet
from ..errors import StickFormRefused
from ..geometry.colouring import shared_particle_pairs
from ..launches import FLOAT, INT, VEC2I, BoundStage, PhaseTask, start_compliant_substep

CLUSTER_PARTICLES = 256
"""Particles a cluster owns: a triangle or quad mesh's cluster then holds about 1,500 sticks in 12 colours, so
each colour's sticks take one pass of a block's threads. Larger clusters swept a 1024^2 mesh a little faster, but
give a 512^2 mesh fewer blocks a launch than an H100 has multiprocessors, and a block twice the shared memory
(bench/results/mesh/batched-staging)."""
CLUSTER_BLOCK = 256
"""Threads per block of the clustered sweep: more than a colour's sticks (half the threads sit out each colour), but
each lane's staging batch is half as long and the block has twice the warps to hide its loads' latency: faster than
128 on an H100 and an H200 (bench/results/mesh/batched-staging)."""
MIN_CHAINED_PARTICLES = 640 * 640
"""From this many particles on, a clustered sweep is chained: one launch a sweep, each block taking the next cluster
and waiting only for its neighbours (kernels/stick_clusters.py), rather than a launch per cluster colour; the same
positions bit for bit. On an H100 it took 7-13% off a triangle mesh's frame from 640^2 to 1024^2, and cost 6-10% at
512^2, where every cluster of a sweep fits on the GPU at once (bench/results/mesh/chained)."""
MAX_CHAINED_NEIGHBOURS = 32
"""The most clusters (itself among them) a cluster of a chained sweep may wait for, which bounds the neighbour
lists' memory before the layout is built; a layout with more (sticks that reach far across the cloth) is swept with
a launch per cluster colour. The benchmark's meshes have at most 9 (bench/results/mesh/chained)."""
MAX_REGION = 2048
"""The most particles a cluster's region (its own and its sticks' other ends) may hold: a stick's two places in it
are packed into one int, 16 bits each."""
MAX_SHARED_BYTES = 48 * 1024
"""The most shared memory a block of the clustered sweep may take (a CUDA block's static limit): its region's
positions and weights, its sticks' packed ends and rest lengths (and, where staged, soft sticks' compliances and
tensions), and its colours' starts."""


def chained_sweep(particles: int) -> bool:
    """Whether a clustered sweep of ``particles`` is chained (MIN_CHAINED_PARTICLES), provided that no cluster has
    more than MAX_CHAINED_NEIGHBOURS neighbours (DeviceClusters checks that once the layout is built)."""
    return particles >= MIN_CHAINED_PARTICLES


def shared_bytes(region_capacity: int, stick_capacity: int, colours: int, staged_soft: bool = False) -> int:
    """The clustered kernel's shared memory a block: 16 bytes a region particle, 8 a stick (16 with a soft stick's
    compliance and tension staged), 4 a colour start."""
    return region_capacity * 16 + stick_capacity * (16 if staged_soft else 8) + (colours + 1) * 4


def stage_soft_sticks(layout: "ClusterLayout") -> bool:
    """Whether a soft clustered sweep stages each stick's compliance and tension in shared memory (else it reads
    and writes them in global memory in the colour loop; the two are the same arithmetic, bit for bit): wherever
    the larger shared arrays stay within a block's limit. On an H100 staged was faster at 512^2 and, since the
    staging's loads are batched and its sticks streamed, at 1024^2 too, though a launch there is then more than
    the GPU holds at once (bench/results/mesh/soft-registers)."""
    return shared_bytes(layout.capacity, layout.stick_capacity, layout.colours, staged_soft=True) <= MAX_SHARED_BYTES


class ClustersRefused(StickFormRefused):
    """The clustered sweep cannot take this model's sticks (the reason in the message). Asked for, it is the
    caller's error; chosen by "auto", the model keeps a launch per colour instead."""


@dataclass
class ClusterLayout:
    """The clustered sweep's order, on the host: clusters numbered in cluster-colour order; per cluster its region
    (``region_start`` (C + 1,), ``region`` the particles) and its sticks by stick colour (``stick_start``
    (C * colours + 1,)); per stored stick its ends as places in its cluster's region (``stick_local``), its rest
    length and its index in the Model's stick arrays (``stick``); ``launches`` (first cluster, clusters) per cluster
    colour; per cluster the clusters whose regions share a particle with its own, and itself (``neighbour_start``
    (C + 1,), ``neighbour``), for the chained sweep's waits; ``capacity`` and ``stick_capacity`` the shared arrays'
    lengths (the largest region and the most sticks a cluster holds, rounded up to 32 and 64, so that near sizes
    share a kernel)."""

    region_start: np.ndarray
    region: np.ndarray
    stick_start: np.ndarray
    stick_local: np.ndarray
    rest: np.ndarray
    stick: np.ndarray
    colours: int
    launches: list[tuple[int, int]]
    neighbour_start: np.ndarray
    neighbour: np.ndarray
    capacity: int
    stick_capacity: int

    @property
    def packed_ends(self) -> np.ndarray:
        """Each stored stick's two places in its region as one int, ``a | b << 16`` (the kernel's form)."""
        return (self.stick_local[:, 0] | self.stick_local[:, 1] << 16).astype(np.int32)


def _regions(cluster_of: np.ndarray, sticks: np.ndarray) -> np.ndarray:
    """Each cluster's region as sorted keys cluster * N + particle: its particles and its sticks' (those whose first
    particle it holds) other ends."""
    n = len(cluster_of)
    return np.unique(np.concatenate([cluster_of * n + np.arange(n), cluster_of[sticks[:, 0]] * n + sticks[:, 1]]))


def neighbour_pairs(keys: np.ndarray, particles: int) -> np.ndarray:
    """(c, d) for every two distinct clusters whose regions (``keys``: cluster * particles + particle) share a
    particle, both ways, sorted by c then d."""
    pairs = np.unique(shared_particle_pairs(keys // particles, keys % particles), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    pairs = np.concatenate([pairs, pairs[:, ::-1]])
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def colour_clusters(keys: np.ndarray, particles: int, clusters: int) -> np.ndarray:
    """A colour per cluster such that the regions (``keys``: cluster * particles + particle) of one colour share
    no particle: greedy, in cluster order (the lowest colour no coloured neighbour holds)."""
    return _greedy_colours(neighbour_pairs(keys, particles), clusters)


def _greedy_colours(pairs: np.ndarray, clusters: int) -> np.ndarray:
    """colour_clusters' colouring, given every neighbouring pair of clusters both ways, sorted (neighbour_pairs)."""
    offsets = np.searchsorted(pairs[:, 0], np.arange(clusters + 1))
    colour = np.full(clusters, -1, np.int64)
    for c in range(clusters):
        taken = colour[pairs[offsets[c]:offsets[c + 1], 1]]
        free = np.ones(len(taken) + 2, bool)
        free[taken[(taken >= 0) & (taken < len(free))]] = False
        colour[c] = int(np.argmax(free))
    return colour


def cluster_layout(sticks: np.ndarray, rest: np.ndarray, stick_colour: np.ndarray, colours: int,
                   rest_positions: np.ndarray, cluster_particles: int = CLUSTER_PARTICLES) -> ClusterLayout:
    """The clustered sweep's layout of ``sticks`` (S, 2) (device particle indices, each with its ``rest`` length
    and its colour, no two sticks of a colour sharing a particle) over particles at ``rest_positions`` (N, 3)."""
    from ..geometry.particle_order import morton_codes

    n = len(rest_positions)
    sticks = np.asarray(sticks, np.int64)
    clusters = -(-n // cluster_particles)
    cluster_of = np.empty(n, np.int64)
    cluster_of[np.argsort(morton_codes(rest_positions), kind="stable")] = np.arange(n) // cluster_particles
    keys = _regions(cluster_of, sticks)
    pairs = neighbour_pairs(keys, n)
    colour = _greedy_colours(pairs, clusters)
    # Renumber the clusters in colour order, so that a cluster colour is one run of consecutive clusters: the
    # regions keep their particles, so their keys are renumbered and sorted again rather than rebuilt.
    renumber = np.empty(clusters, np.int64)
    renumber[np.lexsort((np.arange(clusters), colour))] = np.arange(clusters)
    cluster_of = renumber[cluster_of]
    keys = np.sort(renumber[keys // n] * n + keys % n)
    # The chained sweep's neighbour lists: the same pairs renumbered, and each cluster itself.
    pairs = np.concatenate([renumber[pairs], np.repeat(np.arange(clusters), 2).reshape(-1, 2)])
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    neighbour_start = np.searchsorted(pairs[:, 0], np.arange(clusters + 1))
    region_start = np.zeros(clusters + 1, np.int64)
    np.cumsum(np.bincount(keys // n, minlength=clusters), out=region_start[1:])
    stick_cluster = cluster_of[sticks[:, 0]]
    order = np.lexsort((np.arange(len(sticks)), stick_colour, stick_cluster))
    sticks, stick_cluster = sticks[order], stick_cluster[order]
    local = np.stack([np.searchsorted(keys, stick_cluster * n + sticks[:, e]) - region_start[stick_cluster]
                      for e in (0, 1)], axis=1)
    stick_start = np.zeros(clusters * colours + 1, np.int64)
    np.cumsum(np.bincount(stick_cluster * colours + stick_colour[order], minlength=clusters * colours),
              out=stick_start[1:])
    sizes = np.bincount(colour, minlength=int(colour.max()) + 1)
    firsts = np.r_[0, np.cumsum(sizes)[:-1]]
    largest = int(np.diff(region_start).max())
    most_sticks = int(np.diff(stick_start[::colours]).max())
    layout = ClusterLayout(region_start.astype(np.int32), (keys % n).astype(np.int32), stick_start.astype(np.int32),
                           local.astype(np.int32), np.asarray(rest, np.float32)[order], order,
                           colours, [(int(f), int(s)) for f, s in zip(firsts, sizes)],
                           neighbour_start.astype(np.int32), pairs[:, 1].astype(np.int32), -(-largest // 32) * 32,
                           -(-most_sticks // 64) * 64)
    check_layout(layout, sticks)
    return layout


def check_layout(layout: ClusterLayout, sticks: np.ndarray) -> None:
    """Raise AssertionError unless the layout is a race-free sweep of every stick once: each stored stick's local
    ends are its ends, and the regions of one cluster colour share no particle."""
    owner = np.repeat(np.arange(len(layout.region_start) - 1), np.diff(layout.region_start))
    first = layout.region_start[:-1]
    stick_owner = np.repeat(np.arange(len(layout.stick_start) - 1) // layout.colours, np.diff(layout.stick_start))
    for e in (0, 1):
        if not np.array_equal(layout.region[first[stick_owner] + layout.stick_local[:, e]], sticks[:, e]):
            raise AssertionError("a clustered stick's local end is not its particle")
    if not np.array_equal(np.sort(layout.stick), np.arange(len(sticks))):
        raise AssertionError("the clusters do not hold every stick exactly once")
    for start, count in layout.launches:
        mine = (owner >= start) & (owner < start + count)
        if np.bincount(layout.region[mine]).max(initial=0) > 1:
            raise AssertionError("two clusters of one cluster colour share a particle")
    listed = np.stack([np.repeat(np.arange(len(layout.neighbour_start) - 1),
                                 np.diff(layout.neighbour_start)), layout.neighbour], axis=1)
    sharing = shared_particle_pairs(owner, layout.region)
    sharing = np.concatenate([sharing, sharing[:, ::-1], np.repeat(np.arange(len(first)), 2).reshape(-1, 2)])
    if not np.array_equal(np.unique(sharing, axis=0), listed):
        raise AssertionError("a cluster's neighbours are not the clusters whose regions share a particle with its own")


class StickClusters(ConstraintSet):
    """Stick arrays swept cluster by cluster in shared memory (``sticks = "clustered"``; kernels/stick_clusters.py):
    one launch per cluster colour, XPBD where a stick is soft. The same projections as Sticks in another order
    (block Gauss-Seidel), so not the same positions bit for bit."""

    name = "stick clusters"

    def needed(self, req) -> bool:
        return req.sticks > 0 and req.stick_clusters

    def device_bytes(self, req) -> int:
        """An upper bound, known before the layout is built: the Model's stick arrays (ends, rest, weight; the
        stretch readback reads them); per stored stick its packed local ends and rest (soft sticks: the Model's
        compliance, the stored one and the tension too); the regions, at most every particle and one other end per
        stick; the region starts; and a stick start per cluster and colour, for at most MAX_COLOURS colours."""
        from ..geometry.colouring import MAX_COLOURS

        clusters = -(-req.particles // CLUSTER_PARTICLES)
        soft = req.sticks * 3 * FLOAT if req.compliant else 0  # the Model's compliances, the stored ones, tensions
        # A chained sweep's neighbour lists (at most MAX_CHAINED_NEIGHBOURS a cluster, and their starts) and the
        # solver's chain (three counts, a count per cluster, a flag).
        chain = 0
        if chained_sweep(req.particles):
            chain = (clusters * MAX_CHAINED_NEIGHBOURS + clusters + 1) * INT + (clusters + 4) * INT
        return (req.sticks * (VEC2I + 2 * FLOAT) + req.sticks * (INT + FLOAT) + (req.particles + req.sticks) * INT
                + (clusters + 1) * INT + (clusters * MAX_COLOURS + 1) * INT + soft + chain)

    def build(self, model, scene, device):
        if model.colouring is None or model.colouring.overflow:
            raise ClustersRefused("sticks = 'clustered' needs a colouring whose every colour's sticks share no "
                                   "particle, but the graph colouring put some sticks in its overflow colour: use "
                                   "sticks = 'explicit'")
        colour = np.repeat(np.arange(len(model.colour_ranges)), [n for _, n in model.colour_ranges])
        layout = cluster_layout(model.host_sticks, model.host_rest, colour, len(model.colour_ranges),
                                model.rest_positions, CLUSTER_PARTICLES)
        if layout.capacity > MAX_REGION:
            raise ClustersRefused(f"sticks = 'clustered': a cluster's region (its particles and its sticks' other "
                                   f"ends) holds {layout.capacity} particles, above the {MAX_REGION} a stick's "
                                   "packed ends can name (sticks reach far across the cloth): use sticks = 'explicit'")
        shared = shared_bytes(layout.capacity, layout.stick_capacity, layout.colours)
        if shared > MAX_SHARED_BYTES:
            raise ClustersRefused(f"sticks = 'clustered': a cluster's region of {layout.capacity} particles and "
                                   f"{layout.stick_capacity} sticks take {shared} bytes of shared memory, above the "
                                   f"{MAX_SHARED_BYTES} a block may hold (sticks reach far across the cloth, or many "
                                   "sticks meet at a particle): use sticks = 'explicit'")
        compliance = model.stick_compliance.numpy()[layout.stick] if model.compliant else None
        return DeviceClusters(layout, compliance, model.particle_count, device)

    def bind(self, model, state, solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.stick_clusters import relax_stick_clusters

        data = model.constraints[self.name]
        soft = data.compliance is not None
        chained = data.neighbour is not None
        kernel = relax_stick_clusters(data.capacity, data.stick_capacity, data.colours, soft,
                                      stage_soft=data.stage_soft, block_dim=CLUSTER_BLOCK, chained=chained)
        # XPBD: the tension of each stick over the substep's sweeps, in the clusters' order of the sticks.
        tension = solver.scratch("cluster_tension", len(data.rest), float) if soft else data.no_tension
        compliance = data.compliance if soft else data.no_tension
        if chained:
            chain = solver.cached("cluster_chain", lambda: ClusterChain(data.clusters, model.device))
            launches = [(0, data.clusters)]
            waits = [data.neighbour_start, data.neighbour, chain.counts, chain.done, chain.order_broken]
        else:
            launches = data.launches
            waits = [data.no_ints] * 5
        tasks = []
        for first, count in launches:
            inputs = [state.particle_q, model.inv_mass, data.region_start, data.region, data.stick_start,
                      data.stick_ends, data.rest, compliance, 0.0, tension, first, *waits]
            launch = wp.launch_tiled(kernel, dim=[count], block_dim=CLUSTER_BLOCK, record_cmd=True,
                                     device=model.device, inputs=inputs)
            tasks.append(PhaseTask(kernel.key, launch.launch, launch))
        prepare = start_compliant_substep([task.launch for task in tasks], tension) if soft else None
        # One thread runs a cluster colour: on the CPU a tiled launch's shared memory is one buffer for the
        # process, so two threads' launches would write over each other. The CPU thread team's other threads wait.
        idle = [None] * (solver.threads - 1)
        return BoundStage(prepare, [[task, *idle] for task in tasks])


class ClusterChain:
    """The chained sweep's state on the device, kept by the solver from launch to launch: ``counts`` (3,) the
    clusters taken and finished in the running launch, and the sweeps finished before it; ``done`` (C,) the sweeps
    each cluster has finished; ``order_broken`` (1,) set on the CPU where a cluster would have had to wait."""

    def __init__(self, clusters: int, device):
        import warp as wp

        self.counts = wp.zeros(3, dtype=int, device=device)
        self.done = wp.zeros(clusters, dtype=int, device=device)
        self.order_broken = wp.zeros(1, dtype=int, device=device)


class DeviceClusters:
    """A ClusterLayout's arrays on the device."""

    def __init__(self, layout: ClusterLayout, compliance: np.ndarray | None, particles: int, device):
        import warp as wp

        self.region_start = wp.array(layout.region_start, dtype=int, device=device)
        self.region = wp.array(layout.region, dtype=int, device=device)
        self.stick_start = wp.array(layout.stick_start, dtype=int, device=device)
        self.clusters = len(layout.region_start) - 1
        # A chained sweep's neighbour lists; None where the sweep takes a launch per cluster colour.
        self.neighbour_start = self.neighbour = None
        if chained_sweep(particles) and np.diff(layout.neighbour_start).max() <= MAX_CHAINED_NEIGHBOURS:
            self.neighbour_start = wp.array(layout.neighbour_start, dtype=int, device=device)
            self.neighbour = wp.array(layout.neighbour, dtype=int, device=device)
        self.stick_ends = wp.array(layout.packed_ends, dtype=int, device=device)
        self.rest = wp.array(layout.rest, dtype=float, device=device)
        # Soft sticks' compliances (m/N) in the stored order; None where every stick is rigid.
        self.compliance = None if compliance is None else wp.array(compliance, dtype=float, device=device)
        self.no_tension = wp.empty(0, dtype=float, device=device)  # the rigid kernel's unread XPBD arrays
        self.no_ints = wp.empty(0, dtype=int, device=device)  # the chain's arrays, unread by a launch per colour
        self.colours = layout.colours
        self.launches = layout.launches
        self.capacity = layout.capacity
        self.stick_capacity = layout.stick_capacity
        # Soft sticks' compliance and tension in shared memory (True) or read in global memory (stage_soft_sticks).
        self.stage_soft = compliance is not None and stage_soft_sticks(layout)
