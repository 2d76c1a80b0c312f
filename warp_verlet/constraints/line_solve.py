"""Line solves: ``line_passes = n`` on a grid cloth solves every row and every column of its structural sticks
exactly, ``n`` times, at the start of each substep's relaxation (kernels/line_solve.py).

Why: a Gauss-Seidel sweep carries a correction about one stick along a row per colour pass, so where nothing but
contact holds the cloth up (a drape) it stretches in proportion to the grid's size, and tethers cannot help (they
need pins). A row of structural sticks is a chain, and one Newton step on a chain's stick lengths is a tridiagonal
system, solved exactly by cyclic reduction: the correction reaches the whole row at once. A pass solves every row,
then every column (Gauss-Seidel across the two), and the sweeps then make the final projection of every family as
before. Rows and columns of a flat net meet at right angles, so solving one family moves the other's lengths only
to second order: a pass leaves the structural net nearly exact.

Where the colliders touch the cloth, the lines must not push it into them nor lift it off: the stage clamps the
Verlet prediction once (the colliders placed for the substep first), and each particle the clamp moved slides
along the collider in the solve, its inverse mass taken as w (I - c c^T) along the direction c the clamp pushed it
(launches.clamp_noting_normals: friction tilts the particle's move, so with friction the pushes are noted). (The
clamp after the sweeps still runs, as the substep's last word.)

Only the structural sticks are solved, and they must be rigid: a row's exact lengths are what the solve is for.
The shear and bend families are left to the sweeps. A cloth whose shear and bend sticks are rigid too cannot
drape without stretching (two rigid sticks along a row and a rigid bend stick across both hold the row straight,
so such a cloth is a flat plate); give them a compliance (docs/method.md, "Line solves").
"""

from __future__ import annotations

import numpy as np

from .kind import ConstraintSet
from ..launches import FLOAT, INT, VEC3, BoundStage, clamp_noting_normals, noted_pushes
from ..scene_keys import Key, integer

LINE_THREADS = 256
"""Threads of a CUDA block, which solves one line (the CPU runs one lane a block)."""
LINE_MAX_REGISTERS: int | None = None
"""A CUDA thread's registers at most (None: the compiler's choice). A cap of 64 measured slower at 1024²
(bench/results/line_solve/README.md), so there is none; bench.line_solve --registers tries others."""
MAX_LINE_STICKS = 2048
"""The longest line the solve takes: a block's shared arrays hold 72 bytes a stick (84 with float64 positions), so
2048 take 147 KB (172 KB), under a GPU block's shared-memory limit (227 KB on an H100)."""

LINE_PASSES = Key(
    "line_passes", integer(0, 100), 0, type="integer", unit="passes", default_text="`0`", allowed="0 … 100",
    doc="Solves of every row and then every column of the cloth's structural sticks, at the start of each "
        "substep's relaxation, each a Newton step on the line's lengths (particles on a collider slide along it). "
        "They carry a correction across the whole cloth at once, which the sweeps cannot: a large cloth held up by "
        "contact otherwise stretches, and with tethers a pinned cloth converges further. A pass is exact for a "
        "straight line; a line that bends sharply "
        "within a substep (a long line swinging free, heavy particles hung on light ones) needs more passes. 0 "
        "leaves them out. A grid cloth with rigid structural sticks that cannot tear, at most 2049 particles a "
        "side; its shear and bend sticks should have a `compliance`, or the cloth cannot drape without stretching.")


def passes_of(spec) -> int:
    return spec.options.get(LINE_PASSES.name) or 0


def _line_cloths(scene) -> list:
    return [c for c in scene.cloths if passes_of(c)]


def why_no_lines(spec) -> str | None:
    """Why the cloth ``spec`` cannot take line passes, or None when it can."""
    if spec.mesh is not None:
        return "a mesh cloth has no rows and columns"
    if "structural" not in spec.sticks:
        return "the cloth has no structural sticks"
    if "structural" in spec.compliance:
        return "its structural sticks are soft (compliance), and a line solve makes them exact"
    if spec.tears:
        return "the cloth can tear (tear_threshold or tear_tension), and a torn row is no longer one line"
    if max(spec.resolution) - 1 > MAX_LINE_STICKS:
        return f"its lines are longer than {MAX_LINE_STICKS} sticks ({max(spec.resolution) - 1})"
    return None


def capacity_of(sticks: int) -> int:
    """The kernel's capacity for lines of at most ``sticks`` sticks: the next power of two (at least 2)."""
    return max(2, 1 << (max(sticks, 1) - 1).bit_length())


class LineData:
    """The lines of every cloth with line passes: ``lines`` (L,) vec4i (first particle, sticks, step between its
    particles, the index of its first stick's rest length in ``rest``), every row, then every column (from
    ``column_start``), each group ordered by its cloth's passes, most first; ``rest`` float32 m (per cloth, its
    stick lengths along a row, then along a column); ``passes`` the most any cloth asks, and ``row_lines[p]`` and
    ``column_lines[p]`` how many leading rows and columns pass p solves (those of the cloths asking more than p);
    ``capacity`` the kernel's, for the longest line."""

    def __init__(self, model, scene, device):
        import warp as wp

        from ..core.model import grid_axes, squared_steps

        rows_table, cols_table, rest, passes = [], [], [], []
        longest = 1
        for slot, spec in zip(model.cloths, scene.cloths):
            n = passes_of(spec)
            if not n:
                continue
            top = slot.topology
            rows, cols, first = top.rows, top.cols, slot.first
            # The sticks' rest lengths along a row and along a column, as the implicit grid sticks take them.
            x, row = grid_axes(top)
            base = sum(len(r) for r in rest)
            rest += [np.sqrt(squared_steps(x, 1)), np.sqrt(squared_steps(row, 1))]
            if cols > 1:
                rows_table += [(first + r * cols, cols - 1, 1, base, n) for r in range(rows)]
            if rows > 1:
                cols_table += [(first + c, rows - 1, cols, base + cols - 1, n) for c in range(cols)]
            longest = max(longest, rows - 1, cols - 1)
            passes.append(n)
        self.passes = max(passes)
        self.capacity = capacity_of(longest)
        # Each launch range holds the lines of the cloths asking at least that many passes: sorted by passes
        # (descending), pass p launches the leading lines whose cloth asks more than p.
        rows_table.sort(key=lambda line: -line[4])
        cols_table.sort(key=lambda line: -line[4])
        table = rows_table + cols_table
        self.row_lines = [sum(1 for line in rows_table if line[4] > p) for p in range(self.passes)]
        self.column_lines = [sum(1 for line in cols_table if line[4] > p) for p in range(self.passes)]
        self.column_start = len(rows_table)
        self.lines = wp.array(np.asarray([line[:4] for line in table], np.int32).reshape(-1, 4), dtype=wp.vec4i,
                              device=device)
        self.rest = wp.array(np.concatenate(rest).astype(np.float32), dtype=float, device=device)


class LineSolves(ConstraintSet):
    """Exact solves of a grid cloth's rows and columns of structural sticks (kernels/line_solve.py), once a
    substep before the sweeps, after a clamp of the prediction to the colliders."""

    name = "line solves"
    reads_positions_before_sweeps = True
    clamps_before_sweeps = True
    cloth_keys = (LINE_PASSES,)

    def check_cloth(self, spec, table):
        if not passes_of(spec):
            return None
        why = why_no_lines(spec)
        if why is not None:
            raise table.error(LINE_PASSES.name, f"line passes need a grid cloth with rigid structural sticks that "
                                                f"cannot tear, at most {MAX_LINE_STICKS + 1} particles a side; {why}")
        return None

    def count(self, scene):
        """(lines, rest lengths, whether the scene has colliders) of the cloths with line passes, or 0."""
        cloths = _line_cloths(scene)
        if not cloths:
            return 0
        lines = sum(r * (c > 1) + c * (r > 1) for r, c in (spec.resolution for spec in cloths))
        rest = sum(r - 1 + c - 1 for r, c in (spec.resolution for spec in cloths))
        return lines, rest, int(bool(scene.colliders))

    def needed(self, req) -> bool:
        return bool(req.count(self.name))

    def device_bytes(self, req) -> int:
        # a vec4i per line, a rest length per row and column gap (Model); with colliders, a position snapshot and
        # a contact normal per particle (solver), and with friction each particle's pushes summed
        lines, rest, colliders = req.count(self.name)
        pushes = VEC3 if req.collider_friction else 0
        contact = req.particles * (req.position_bytes + VEC3 + pushes) if colliders else 0
        return lines * 4 * INT + rest * FLOAT + contact

    def build(self, model, scene, device):
        return LineData(model, scene, device)

    def bind(self, model, state, solver) -> BoundStage:
        import warp as wp

        from warp_verlet.kernels.line_solve import line_solve_kernel

        data, x = model.constraints[self.name], state.particle_q
        n = model.particle_count
        pushes = noted_pushes(model, solver, "line")
        bound = [kind.bind(model, state, pushes) for kind, _ in model.colliders.kinds]
        clamps = [task for launches in bound for task in launches.clamps]
        if clamps:
            snapshot = solver.scratch("line_snapshot", n, model.position_dtype)
            normal = solver.scratch("line_normals", n, wp.vec3)
            contact = clamp_noting_normals(x, clamps, snapshot, normal, pushes)
        else:
            normal = wp.empty(0, dtype=wp.vec3, device=model.device)  # not read
            contact = []
        # On the CPU one thread runs every line, one lane a block: a tiled launch's shared memory is one buffer for
        # the process there, so pieces of lines run by the relaxation's threads at once would write over each
        # other (as for the tiled sweeps, constraints/sticks.py).
        threads = LINE_THREADS if model.device.is_cuda else 1
        kernel = line_solve_kernel(data.capacity, model.position_dtype, threads, LINE_MAX_REGISTERS)

        def lines(first: int, count: int):
            return wp.launch_tiled(kernel, dim=[count], block_dim=threads, record_cmd=True, device=model.device,
                                   inputs=[x, model.inv_mass, int(bool(clamps)), normal,
                                           data.lines[first:first + count], data.rest])

        passes = []
        for p in range(data.passes):
            if data.row_lines[p]:
                passes.append(lines(0, data.row_lines[p]))
            if data.column_lines[p]:
                passes.append(lines(data.column_start, data.column_lines[p]))
        tasks = [task.run for task in contact]

        def run(state, dt: float) -> None:
            for task in tasks:
                task()
            for launch in passes:
                launch.launch()

        return BoundStage(run, [])
