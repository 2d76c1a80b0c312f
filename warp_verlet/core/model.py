"""The static data of a scene on one device: every cloth's particles in one array, sticks sorted by colour.

A Model is immutable once built: nothing in a run writes it (tearing zeroes the State's stick weights). So
one model serves any number of states (checkpoints, clones, a batch of shots).

All cloths share one particle array (cloth ``k`` owns a contiguous slice), so one launch serves every
cloth. Colour ``c`` of one cloth and colour ``c`` of another touch disjoint particles, so their union is
still a valid colour: a step costs as many launches as the most-coloured cloth, not the sum.

Only what the scene's solver needs is allocated: the coloured solver gets per-colour contiguous stick
arrays; the Jacobi solver gets a per-particle neighbour list (CSR) instead. Tear lengths exist only when a
cloth can tear.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import warp as wp

from ..colliders import ColliderModel
from ..geometry.colouring import Colouring, check_partition, graph_colouring, grid_colouring, stick_order
from ..errors import ArgumentError
from ..constraints import kinds as constraint_kinds
from ..constraints.stick_clusters import ClustersRefused
from ..constraints.tethers import TetherTable, build_tethers
from ..input.scene import Scene
from .stages import AERODYNAMICS, MAX_UNIFORM_MASS_PINS, Requirements
from ..geometry.faces import edge_faces
from ..geometry.mesh_cloth import STRUCTURAL
from ..geometry.particle_order import inverse_order, locality_order, reorder_topology, wants_locality_order
from ..geometry import topology as topology_module
from ..geometry.topology import (BEND_H, BEND_V, FAMILY_OF_CLASS, SHEAR_ANTI, SHEAR_DIAG, STRUCT_H, STRUCT_V,
                                 ClothTopology, build_cloth)


PARTICLE_ORDERS = ("auto", "morton", "input")


@dataclass(frozen=True)
class ClothSlot:
    """Where one cloth lives in the shared particle array.

    ``topology`` is the cloth as the scene numbers its particles: what the cache, the views and the user see.
    ``reordered`` is the same cloth with its particles in the order the device holds them, where the Model
    renumbered them (a mesh cloth, warp_verlet/geometry/particle_order.py), else None; ``device_topology`` is
    whichever of the two the device holds, the one the Model and the constraint kinds build from."""

    topology: ClothTopology
    first: int  # index of its first particle
    reordered: ClothTopology | None = None

    @property
    def device_topology(self) -> ClothTopology:
        return self.topology if self.reordered is None else self.reordered

    @property
    def name(self) -> str:
        return self.topology.name

    @property
    def count(self) -> int:
        return self.topology.particle_count

    @property
    def particles(self) -> slice:
        return slice(self.first, self.first + self.count)


def stick_form(sticks: str, colouring: str, device) -> str:
    """The sticks' form asked of Requirements.of for a Model on ``device``. "auto" means implicit grid sticks where the
    scene allows them on a GPU, where a sweep is bound by memory traffic and they save it; on the CPU it means
    stick arrays, which measured faster there (the arrays stay in its caches, and the computed ends and rest
    lengths cost integer divisions and a square root per stick; bench/results/implicit_grid). Implicit sticks
    follow the analytic colouring's order, so Warp's graph colouring makes "auto" explicit (and "implicit" or
    "tiled" an error). Where "auto" sweeps tile by tile is Requirements.of's choice (core/stages.py)."""
    if colouring == "graph" and sticks in ("implicit", "tiled"):
        raise ArgumentError(f"sticks={sticks!r} projects in the analytic grid colouring's order; "
                            "colouring='graph' needs sticks='explicit' or 'auto'")
    if sticks == "auto" and (colouring == "graph" or device.is_cpu):
        return "explicit"
    return sticks


def grid_axes(topology: ClothTopology) -> tuple[np.ndarray, np.ndarray]:
    """A grid's rest coordinates along its columns (x, per column) and along its rows (y for a vertical cloth,
    z for a horizontal one, per row), as float64 of the float32 positions. Checks that every particle's
    position is (x of its column, that row coordinate of its row, one constant), which the implicit sticks'
    rest lengths rely on."""
    rows, cols = topology.rows, topology.cols
    p = topology.positions.reshape(rows, cols, 3).astype(np.float64)
    along_rows = 1 if np.ptp(p[:, 0, 1]) > 0 or np.ptp(p[:, 0, 2]) == 0 else 2
    fixed = 3 - along_rows
    x, row = p[0, :, 0], p[:, 0, along_rows]
    if not (np.array_equal(p[..., 0], np.broadcast_to(x, (rows, cols)))
            and np.array_equal(p[..., along_rows], np.broadcast_to(row[:, None], (rows, cols)))
            and (p[..., fixed] == p[0, 0, fixed]).all()):
        raise AssertionError(f"cloth {topology.name!r}: grid positions are not a uniform lattice")
    return x, row


def power_of_two_bits(n: int) -> int:
    """The least b with 2^b >= n: the implicit grid kernels run 2^b threads per row of n."""
    return max(int(n) - 1, 0).bit_length()


def squared_steps(axis: np.ndarray, step: int) -> np.ndarray:
    """(axis[k + step] - axis[k])^2 in float64, rounded as numpy rounds the explicit rest lengths' squares."""
    return np.square(axis[step:] - axis[:-step]) if len(axis) > step else np.zeros(0)


@dataclass(frozen=True)
class GridColourDevice:
    """One colour of implicit grid sticks: the kernel's GridColour, its anchors (rows x cols: its sticks), the
    rest-length and squared-step tables it reads, its family's compliance (0: rigid) and where its sticks'
    tensions start in the solver's scratch."""

    layout: object  # kernels.grid_relax.GridColour
    pins: wp.array  # the pins, where the layout says the free particles share one weight (else empty)
    rows: int
    cols: int
    col_rest: wp.array
    row_rest: wp.array
    col_sq: wp.array
    row_sq: wp.array
    compliance: float
    tension_first: int

    @property
    def count(self) -> int:
        return self.rows * self.cols


# Per grid class (topology's order): (dr, dc, first column, parity along "row" or "col", q).
GRID_DIRECTIONS = {
    STRUCT_H: (0, 1, 0, "col", 1), STRUCT_V: (1, 0, 0, "row", 1),
    SHEAR_DIAG: (1, 1, 0, "row", 1), SHEAR_ANTI: (1, -1, 1, "row", 1),
    BEND_H: (0, 2, 0, "col", 2), BEND_V: (2, 0, 0, "row", 2),
}


class GridDevice:
    """The implicit grid sticks of one grid cloth: its colours in the analytic colouring's order (class in the
    sweep's order, topology.SWEEP_ORDER, then parity: warp_verlet/geometry/colouring.grid_colouring) and the tables
    their rest lengths come from: per column for 1 and 2 columns apart and per row for 1 and 2 rows apart, the
    squared steps (float64) and their roots (the rest lengths of sticks along one axis, float32)."""

    def __init__(self, slot: "ClothSlot", spec, device, uniform: bool):
        from warp_verlet.kernels.grid_relax import GridColour

        top = slot.topology
        rows, cols = top.rows, top.cols
        x, row = grid_axes(top)
        squares = {"col1": squared_steps(x, 1), "col2": squared_steps(x, 2),
                   "row1": squared_steps(row, 1), "row2": squared_steps(row, 2)}
        sq = {k: wp.array(v, dtype=wp.float64, device=device) for k, v in squares.items()}
        # sqrt(d^2) rounded to float32: what np.linalg.norm gives the explicit rest length of a one-axis stick.
        rest = {k: wp.array(np.sqrt(v).astype(np.float32), dtype=float, device=device) for k, v in squares.items()}
        self.col_sq1, self.row_sq1 = sq["col1"], sq["row1"]  # shear sticks (and the budget's stretch)
        self.col_rest1, self.col_rest2 = rest["col1"], rest["col2"]
        self.row_rest1, self.row_rest2 = rest["row1"], rest["row2"]
        weight = top.inv_mass
        free = np.unique(weight[weight > 0])
        pinned = np.flatnonzero(weight == 0)
        # The kernels find a particle's weight without reading it when the free particles share one and the pins
        # are few (Requirements.weight_pins, from the scene: no particle masses, at most MAX_UNIFORM_MASS_PINS pins).
        if uniform and not (len(free) <= 1 and len(pinned) <= MAX_UNIFORM_MASS_PINS):
            raise AssertionError(f"cloth {top.name!r}: its free particles do not share one weight")
        if uniform:
            self.pins = wp.array((pinned + slot.first).astype(np.int32), dtype=int, device=device)
        no_pins = wp.empty(0, dtype=int, device=device)
        colours, soft = [], 0
        for cls in topology_module.SWEEP_ORDER:
            family = FAMILY_OF_CLASS[cls]
            if family not in spec.sticks:
                continue
            dr, dc, col_first, parity_axis, q = GRID_DIRECTIONS[cls]
            row_span, col_span = rows - dr, cols - max(dc, 0) - col_first
            if row_span <= 0 or col_span <= 0:
                continue
            compliance = float(spec.compliance.get(family, 0.0))
            for parity in (0, 1):
                along = row_span if parity_axis == "row" else col_span
                kept = int(np.count_nonzero((np.arange(along) // q) % 2 == parity))
                n_rows, n_cols = (kept, col_span) if parity_axis == "row" else (row_span, kept)
                if n_rows * n_cols == 0:
                    continue
                g = GridColour()
                g.first_particle, g.grid_cols, g.cols, g.col_bits = slot.first, cols, n_cols, power_of_two_bits(n_cols)
                g.row_first, g.col_first = 0, col_first
                g.row_q, g.col_q = (q, 0) if parity_axis == "row" else (0, q)
                g.parity, g.dr, g.dc = parity, dr, dc
                g.use_col, g.use_row, g.col_shift = int(dc != 0), int(dr != 0), -1 if dc < 0 else 0
                g.uniform_mass, g.free_weight = int(uniform), float(free[0]) if uniform and len(free) else 0.0
                col_rest = self.col_rest2 if abs(dc) == 2 else self.col_rest1
                row_rest = self.row_rest2 if dr == 2 else self.row_rest1
                colours.append(GridColourDevice(g, self.pins if uniform else no_pins, n_rows, n_cols, col_rest,
                                                row_rest, self.col_sq1, self.row_sq1, compliance,
                                                soft if compliance > 0.0 else 0))
                soft += n_rows * n_cols if compliance > 0.0 else 0
        self.colours: tuple[GridColourDevice, ...] = tuple(colours)
        self.soft_sticks = soft
        self.rows, self.cols = rows, cols


class GridTethersDevice:
    """Implicit tethers of one grid cloth: its pins (global indices, in the cloth's pin order) and, per pin, the
    squared column and row differences of the rest grid to it (float64), from which each free particle finds
    its nearest ``tethers`` pins and their lengths (times ``scale``) in the kernel."""

    def __init__(self, slot: "ClothSlot", spec, tethers: int, device):
        top = slot.topology
        x, row = grid_axes(top)
        pinned = np.asarray(top.pinned, np.int64)
        pin_row, pin_col = pinned // top.cols, pinned % top.cols
        self.first_particle, self.rows, self.cols = slot.first, top.rows, top.cols
        self.col_bits = power_of_two_bits(top.cols)
        self.tethers = min(tethers, len(pinned))
        self.scale = float(spec.tether_scale)
        self.pins = wp.array((pinned + slot.first).astype(np.int32), dtype=int, device=device)
        self.pin_col_sq = wp.array2d(np.square(x[None, :] - x[pin_col][:, None]), dtype=wp.float64, device=device)
        self.pin_row_sq = wp.array2d(np.square(row[None, :] - row[pin_row][:, None]), dtype=wp.float64, device=device)


class Model:
    """Device arrays (read by the kernels, never written) and the host copies the metrics need.

    Particles (N), in the order the device holds them: ``inv_mass`` (N,) float32, 1/kg, 0 for a pin;
    ``rest_positions`` (N, 3) float32, m (host). A mesh cloth's particles may be held in Morton order of their rest
    positions (``particle_order``; warp_verlet/geometry/particle_order.py: a launch then reads memory forward); a
    grid's stay in row-major order. ``scene_particle`` (N,) int32: the scene's index (cloth
    after cloth, each cloth's particles as its ``ClothSlot.topology`` numbers them) of each device particle, and
    ``device_particle`` (N,) int32 the inverse, the device index of each scene particle; both None when the two
    orders are the same. Every index a Model holds (sticks, tethers, faces, the constraint kinds' data) is a
    device index; ``to_scene_order`` and ``to_device_order`` convert per-particle arrays, and the State's host
    readbacks (positions, set_positions, set_velocity) speak the scene's order.
    Precision: ``precision`` ("float32" or "float64", the scene's ``simulation.precision`` resolved), and the
    State's position types ``position_dtype`` (``wp.vec3`` or ``wp.vec3d``), ``position_scalar``
    (``wp.float32`` or ``wp.float64``) and ``host_position_dtype`` (numpy's). Only positions change type:
    every array of the Model is float32 either way.
    Coloured solver, per stick in colour order (M): ``stick_ends`` (M,) vec2i particle indices,
    ``stick_rest`` (M,) float32 m, ``stick_weight`` (M,) float32 (all 1: the intact weights a State starts
    from), ``stick_compliance`` (M,) float32 m/N or None when every stick is rigid; ``colour_ranges`` the
    (first, count) of each colour, whose sticks are sorted by first particle, then second (colouring.stick_order).
    Jacobi solver: the per-particle CSR ``neighbour_start`` (N + 1,),
    ``neighbour``, ``neighbour_rest`` and ``neighbour_weight`` (2M,) instead. Tearing (only when a cloth can
    tear): ``tear_ends`` and ``tear_length`` (E,), one entry per stick (coloured) or per stick end (Jacobi);
    where a cloth tears by tension (coloured only), ``tear_force`` (M,) float32 N (+inf: never by tension).
    Tethers (only when a cloth uses them; a row per particle of the tethered cloths' span, T rows from
    ``tether_table.first``, K pins each, constraints/tethers.TetherTable): ``tether_pin`` (T, K) int32 (-1: none;
    -2 in the first slot: the row's particle is pinned) and ``tether_length`` (T, K) float32 m, the rest-pose
    lengths a State's copy starts from when a cloth can tear. Air (only where ``[simulation.air]`` pushes on a
    face): ``air``, the faces, the particles' face lists, the keyframes and gusts (core/aerodynamics.AirModel), else
    None. Other constraint kinds (warp_verlet/constraints/): ``constraints``,
    kind name -> the device data its ``build`` made, documented in its module.
    """

    def __init__(self, scene: Scene, device, colouring: str = "auto", sticks: str = "auto",
                 requirements: Requirements | None = None, particle_order: str = "auto"):
        """``colouring``: "auto" (analytic when every cloth is a grid, else Warp's graph colouring), "grid"
        (grids only) or "graph". ``sticks``: "auto" (implicit grid sticks on a GPU where the scene allows
        them: stages.implicit_grid_obstacle, :func:`stick_form`), "explicit" or "implicit". ``requirements``: the
        scene's Requirements for that stick form, where the caller has computed them already.
        ``particle_order``: "auto" (a mesh cloth's particles in Morton order on the device where that brings its
        sticks' ends much closer in memory than the scene's order: particle_order.wants_locality_order), "morton"
        (every mesh cloth's in Morton order) or "input" (every cloth's as the scene numbers them); a grid's stay
        in row-major order."""
        if colouring not in ("auto", "grid", "graph"):
            raise ArgumentError(f"colouring must be 'auto', 'grid' or 'graph', got {colouring!r}")
        if particle_order not in PARTICLE_ORDERS:
            raise ArgumentError(f"particle_order must be 'auto', 'morton' or 'input', got {particle_order!r}")
        sticks = stick_form(sticks, colouring, device)
        self.device = device
        self.relaxation = scene.simulation.relaxation
        req = requirements if requirements is not None else Requirements.of(scene, sticks)
        self.precision = req.precision
        self.stick_request = sticks  # what Requirements.of was asked: the solver's Requirements must be asked the same
        self.sticks_form = (("tiled" if req.grid_tiles else "implicit") if req.implicit_grid
                            else "clustered" if req.stick_clusters else "explicit")
        double = self.precision == "float64"
        self.position_dtype = wp.vec3d if double else wp.vec3
        self.position_scalar = wp.float64 if double else wp.float32
        self.host_position_dtype = np.float64 if double else np.float32
        slots, orders, first = [], [], 0
        for spec in scene.cloths:
            topology = build_cloth(spec)
            order = None
            if particle_order != "input" and not topology.is_grid:
                order = locality_order(topology.positions)
                if particle_order == "auto" and not wants_locality_order(topology, order):
                    order = None
            slots.append(ClothSlot(topology, first, None if order is None else reorder_topology(topology, order)))
            orders.append(np.arange(first, first + spec.particle_count, dtype=np.int32) if order is None
                          else order + np.int32(first))
            first += spec.particle_count
        self.cloths: tuple[ClothSlot, ...] = tuple(slots)
        self.particle_count = first
        reordered = any(s.reordered is not None for s in slots)
        self.scene_particle = np.concatenate(orders).astype(np.int32) if reordered else None
        self.device_particle = inverse_order(self.scene_particle) if reordered else None

        # Host copies of everything, concatenated with particle indices made global (device order).
        self.rest_positions = np.concatenate([s.device_topology.positions for s in slots])
        self.host_inv_mass = np.concatenate([s.device_topology.inv_mass for s in slots])
        sticks = np.concatenate([s.device_topology.sticks + s.first for s in slots]).astype(np.int32)
        rest = np.concatenate([s.device_topology.rest_length for s in slots])
        compliance = np.concatenate([s.device_topology.compliance for s in slots])
        family = np.concatenate([s.device_topology.family for s in slots])
        all_grids = all(s.topology.is_grid for s in slots)
        if colouring == "grid" and not all_grids:
            raise ArgumentError("colouring='grid' needs every cloth to be a grid; a mesh cloth takes 'graph' or 'auto'")
        owner = np.repeat(np.arange(len(slots), dtype=np.int32), [len(s.device_topology.sticks) for s in slots])
        # A stick of a cloth that cannot tear gets an infinite tear length: one kernel serves every cloth.
        tear_length = np.concatenate([
            s.device_topology.rest_length * np.float32(spec.tear_threshold) if spec.tear_threshold
            else np.full(len(s.device_topology.rest_length), np.inf, np.float32)
            for s, spec in zip(slots, scene.cloths)
        ]).astype(np.float32)
        # Tearing by tension: a stick's tear force is its cloth's tear_tension (N/m) times the width of cloth it
        # carries, taken as its rest length (the spacing across a structural stick of a square grid); +inf where
        # its cloth sets none.
        tear_force = np.concatenate([
            s.device_topology.rest_length * np.float32(spec.tear_tension) if spec.tear_tension
            else np.full(len(s.device_topology.rest_length), np.inf, np.float32)
            for s, spec in zip(slots, scene.cloths)
        ]).astype(np.float32)
        self.stick_count = len(sticks)

        self.inv_mass = wp.array(self.host_inv_mass, dtype=float, device=device)
        self.has_free_particles = bool((self.host_inv_mass > 0).any())
        self.compliant = bool((compliance > 0).any())
        self.stick_compliance = None

        csr_stick = csr_ends = None  # Jacobi only
        if self.relaxation == "coloured":
            if colouring == "graph" or not all_grids:  # cloths own disjoint particles: one graph serves all
                self.colouring: Colouring | None = graph_colouring(sticks)
            else:
                self.colouring = grid_colouring(np.concatenate([s.topology.grid_class for s in slots]),
                                                np.concatenate([s.topology.anchor for s in slots]))
            check_partition(sticks, self.colouring.colour)  # cheap, and a wrong colouring is a silent race
            order = stick_order(self.colouring.colour, sticks)  # by colour, then first and second particle
            sticks, rest, compliance = sticks[order], rest[order], compliance[order]
            family, owner, tear_length, tear_force = family[order], owner[order], tear_length[order], tear_force[order]
            sizes = self.colouring.sizes
            self.colour_ranges = [(int(a), int(n)) for a, n in zip(np.r_[0, np.cumsum(sizes)[:-1]], sizes) if n > 0]
            if req.implicit_grid:  # the sticks are computed from the grid: no stick arrays on the device
                self.grid = GridDevice(self.cloths[0], scene.cloths[0], device, uniform=req.weight_pins > 0)
                self._hold(self.grid, "grid")
                if [c.count for c in self.grid.colours] != [n for _, n in self.colour_ranges]:
                    raise AssertionError("implicit grid colours differ from the analytic colouring")
            else:
                self.stick_ends = wp.array(sticks, dtype=wp.vec2i, device=device)
                self.stick_rest = wp.array(rest, dtype=float, device=device)
                self.stick_weight = wp.array(np.ones(len(sticks), np.float32), dtype=float, device=device)
                if self.compliant:
                    self.stick_compliance = wp.array(compliance, dtype=float, device=device)
        else:
            self.colouring = None
            self.colour_ranges = []
            csr_stick, csr_ends = self._build_neighbours(sticks, rest, device)

        # Kept on the host for metrics (stretch over structural sticks) in the device order.
        self.host_sticks = sticks
        self.host_rest = rest
        self.host_compliance = compliance  # m/N per stick (0: rigid), for the global correction's springs
        self.host_family = family  # family code per stick (geometry/mesh_cloth: STRUCTURAL, SHEAR, BEND)
        self.structural = family == STRUCTURAL
        self.tears = scene.tears
        self.tension_tears = scene.tears_by_tension  # the scene check keeps it to the coloured solver
        if self.tears:
            self._build_tearing(tear_length, owner, device, csr_stick, csr_ends)
        if self.tension_tears:
            self.tear_force = wp.array(tear_force, dtype=float, device=device)
        self.colliders = ColliderModel(scene, device)
        self.tether_table: TetherTable | None = build_tethers(self.cloths, scene.cloths, scene.tethers_per_particle)
        if req.grid_pins:  # computed in every sweep from the grid: the table stays on the host
            self.grid_tethers = GridTethersDevice(self.cloths[0], scene.cloths[0], scene.tethers_per_particle, device)
            self._hold(self.grid_tethers, "grid_tethers")
        elif self.tether_table is not None:
            table = self.tether_table
            self.tether_pin = wp.array2d(table.pin, dtype=int, device=device)
            self.tether_length = wp.array2d(table.length, dtype=float, device=device)
        self.air = None  # [simulation.air]'s device data (core/aerodynamics.AirModel), where a face feels air
        if AERODYNAMICS.needed(req):
            from .aerodynamics import AirModel

            self.air = AirModel(self, scene, req.air, device)
            self._hold(self.air, "air")
        self.clusters_refused = None  # why "auto" kept a launch per colour where it chose clustered sticks
        self.constraints = {}  # constraint kind name -> the device data its build made (kinds with data only)
        for kind in constraint_kinds():
            if not kind.needed(req):
                continue
            try:
                data = kind.build(self, scene, device)
            except ClustersRefused as refusal:
                if self.stick_request != "auto":
                    raise
                # "auto" chose clustered sticks from the scene alone; the layout (the colouring's overflow, a
                # region's size) is known only now. A launch per colour takes any stick arrays, in less memory, and
                # builds nothing of its own (it sweeps the Model's stick arrays), so the kinds built so far stand.
                self.clusters_refused = str(refusal)
                req = replace(req, stick_clusters=False)
                self.stick_request, self.sticks_form = "explicit", "explicit"
                continue
            if data is not None:
                self.constraints[kind.name] = data
                self._hold(data, kind.name.replace(" ", "_"))
        self.requirements = req  # the scene's Requirements for this model's stick form: the solver's
        self._frozen = True

    def _hold(self, part, prefix: str) -> None:
        """Name ``part``'s device arrays on the Model too (``prefix_name``), where whatever lists the Model's
        arrays (the memory test, the benchmarks' byte counts) finds them."""
        for name, value in vars(part).items():
            if isinstance(value, wp.array):
                setattr(self, f"{prefix}_{name}", value)

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise AttributeError(f"a Model is immutable once built (tried to set {name!r}); "
                                 "time-varying data belongs in the State")
        super().__setattr__(name, value)

    def _build_tearing(self, tear_length, owner, device, csr_stick=None, csr_ends=None) -> None:
        """What ``tear_sticks`` reads (its sticks and their tear lengths), the intact weights a State's live
        copy starts from, and, on the host, which faces each structural stick borders, to hide them when it
        tears.

        The coloured solver's weight belongs to the sticks themselves. The Jacobi solver keeps one per stick
        end (one per CSR entry), so its tear kernel runs over those entries: both ends of a stick see the
        same length (x_j - x_i and x_i - x_j differ only in sign, exactly) and tear together."""
        if csr_stick is None:
            self.tear_ends = self.stick_ends
            self.tear_weight_start = self.stick_weight
            self._tear_entry_stick = np.arange(self.stick_count)
            entry_length = tear_length
        else:
            self.tear_ends = wp.array(csr_ends, dtype=wp.vec2i, device=device)
            self.tear_weight_start = self.neighbour_weight
            self._tear_entry_stick = csr_stick
            entry_length = tear_length[csr_stick]
        self.tear_length = wp.array(entry_length, dtype=float, device=device)
        self.tear_entries_per_stick = 1 if csr_stick is None else 2
        self.stick_cloth = owner
        self.stick_faces = np.full((self.stick_count, 2), -1, np.int32)
        for k, slot in enumerate(self.cloths):
            mine = owner == k
            # Only a face's sides have faces beside them: shear and bend sticks get -1 from edge_faces.
            self.stick_faces[mine] = edge_faces(slot.device_topology.faces, self.host_sticks[mine] - slot.first)

    def _build_neighbours(self, sticks, rest, device) -> tuple[np.ndarray, np.ndarray]:
        """CSR list of (neighbour, rest, weight) per particle for the gather-form Jacobi solver. Returns,
        per CSR entry, its stick and its (particle, neighbour) pair, which tearing needs."""
        n = self.particle_count
        a = np.concatenate([sticks[:, 0], sticks[:, 1]])
        b = np.concatenate([sticks[:, 1], sticks[:, 0]])
        # By particle, then neighbour in the scene's order: a fixed summation order, the same whatever order the
        # device holds the particles in, so a reordered cloth moves bit for bit as one held in the scene's order.
        order = np.lexsort((self.scene_particles(b), a))
        counts = np.bincount(a, minlength=n)
        start = np.zeros(n + 1, np.int32)
        np.cumsum(counts, out=start[1:])
        self.neighbour_start = wp.array(start, dtype=int, device=device)
        self.neighbour = wp.array(b[order].astype(np.int32), dtype=int, device=device)
        self.neighbour_rest = wp.array(np.tile(rest, 2)[order], dtype=float, device=device)
        self.neighbour_weight = wp.array(np.ones(2 * len(sticks), np.float32), dtype=float, device=device)
        return order % max(len(sticks), 1), np.stack([a[order], b[order]], axis=1).astype(np.int32)

    @property
    def colour_count(self) -> int:
        return len(self.colour_ranges)

    def split(self, points: np.ndarray) -> list[np.ndarray]:
        """Per-cloth views of a (particle_count, 3) array (a cloth's particles are its slice in either order)."""
        return [points[s.particles] for s in self.cloths]

    def to_scene_order(self, values: np.ndarray) -> np.ndarray:
        """A per-particle array (N, ...) held in device order, in the scene's order (itself when they agree)."""
        return values if self.device_particle is None else values[self.device_particle]

    def to_device_order(self, values: np.ndarray) -> np.ndarray:
        """A per-particle array (N, ...) given in the scene's order, in device order (itself when they agree)."""
        return values if self.scene_particle is None else values[self.scene_particle]

    def device_particles(self, scene_indices) -> np.ndarray:
        """The device indices of particles given by their scene indices (global: ``slot.first`` + local)."""
        scene_indices = np.asarray(scene_indices)
        return scene_indices if self.device_particle is None else self.device_particle[scene_indices]

    def scene_particles(self, device_indices) -> np.ndarray:
        """The scene indices of particles given by their device indices."""
        device_indices = np.asarray(device_indices)
        return device_indices if self.scene_particle is None else self.scene_particle[device_indices]

    def torn_sticks(self, stick_weight: np.ndarray) -> np.ndarray:
        """Which sticks (in ``host_sticks`` order) are torn, from a host copy of a State's ``stick_weight``."""
        torn = np.zeros(self.stick_count, bool)
        torn[self._tear_entry_stick[stick_weight == 0.0]] = True
        return torn

    def restore_tears(self, state, torn_pairs: np.ndarray) -> None:
        """Mark the sticks between the particle pairs ``torn_pairs`` (K, 2, scene indices) torn in ``state``:
        tears carried over from a simulator of the same particles whose model was rebuilt (another stick or
        particle order). Pairs that are no stick here are ignored."""
        def key(pairs):
            pairs = np.sort(np.asarray(pairs, np.int64).reshape(-1, 2), axis=1)
            return pairs[:, 0] * self.particle_count + pairs[:, 1]
        torn = np.isin(key(self.host_sticks), key(self.device_particles(np.asarray(torn_pairs, np.int64))))
        weight = np.where(torn[self._tear_entry_stick], 0.0, 1.0).astype(np.float32)
        state.stick_weight.assign(weight)
        state.torn_entries.assign(np.array([int((weight == 0.0).sum())], np.int32))

    def hidden_faces(self, torn: np.ndarray) -> list[np.ndarray]:
        """Per cloth, the sorted indices of the faces that border a torn structural stick."""
        faces = self.stick_faces[torn]
        owner = self.stick_cloth[torn]
        out = []
        for k in range(len(self.cloths)):
            f = faces[owner == k].ravel()
            out.append(np.unique(f[f >= 0]).astype(np.int32))
        return out

    def structural_stretch(self, points: np.ndarray, torn: np.ndarray | None = None) -> np.ndarray:
        """|D - L| / L for every structural stick (the cloth's stretch; bend sticks measure bending) that is
        not torn (``torn`` in ``host_sticks`` order), from ``points`` in the scene's order (State.positions)."""
        keep = self.structural if torn is None else self.structural & ~torn
        s = self.host_sticks[keep]
        rest = self.host_rest[keep].astype(np.float64)
        p = self.to_device_order(points).astype(np.float64)
        length = np.linalg.norm(p[s[:, 1]] - p[s[:, 0]], axis=1)
        return np.abs(length - rest) / rest
