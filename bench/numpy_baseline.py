"""Plain numpy Verlet + stick relaxation: what a user writes without this project.

    python -m bench.numpy_baseline [--size 64] [--frames 10] [--substeps 4] [--iterations 8]
                                   [--solver jacobi|coloured|both] [--check]

The same physics as warp_verlet's Simulator on a scene without colliders, vectorised over sticks:

- Verlet in the simulator's summed form (kernels/integrate.py): x += d (delta + x - x_inertial) + a dt^2,
  d = exp(-damping dt), with the exact start delta = -a dt^2 / 2, pins (inverse mass 0) never moving, all in
  float32.
- Jacobi (kernels/relax.py relax_jacobi): every stick's correction is computed from the old positions,
  summed per particle with ``np.bincount`` and averaged over the particle's stick count.
- Coloured Gauss-Seidel (relax_colour): one vectorised update per colour of the simulator's colouring;
  the sticks of one colour share no particle, so a fancy-indexed ``+=`` is race-free.

Sticks (rigid: the model's stick weights, all 1), rest lengths, inverse masses and the colouring are taken from a
``Simulator``'s model, so both sides relax exactly the same sticks (``NumpyCloth.from_scene``); soft sticks
(compliance) and tethers are not reproduced, and such a scene is refused. ``--check``
runs the Warp simulator beside it and prints the largest position difference.
"""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np

from .common import arg_parser, hanging_cloth, quiet_warp, time_frames

MIN_LENGTH = np.float32(1.0e-9)


class NumpyCloth:
    """One scene's particles and sticks as numpy arrays; ``step_frame()`` mirrors ``Simulator.step_frame``."""

    def __init__(self, positions, inv_mass, sticks, rest, weight, colour_ranges, *, dt, substeps, iterations,
                 damping, accel, solver="jacobi"):
        if solver not in ("jacobi", "coloured"):
            raise ValueError(f"solver must be 'jacobi' or 'coloured', got {solver!r}")
        self.solver = solver
        self.x = np.array(positions, dtype=np.float32)
        self.n = len(self.x)
        self.w = np.asarray(inv_mass, dtype=np.float32)
        self.a = np.ascontiguousarray(sticks[:, 0], dtype=np.intp)
        self.b = np.ascontiguousarray(sticks[:, 1], dtype=np.intp)
        self.rest = np.asarray(rest, dtype=np.float32)
        self.k = np.asarray(weight, dtype=np.float32)
        self.colour_ranges = list(colour_ranges)
        self.dt, self.substeps, self.iterations = float(dt), int(substeps), int(iterations)
        self.velocity_scale = np.float32(math.exp(-damping * dt))  # the velocity kept per step, as the kernel
        self.accel = np.asarray(accel, dtype=np.float32)
        self.free = self.w > 0
        self.stick_count = len(self.a)
        # Jacobi: scatter indices for both ends, the stick count of each particle, and w_i / count_i.
        self._ends = np.concatenate([self.a, self.b])
        count = np.bincount(self._ends, minlength=self.n).astype(np.float32)
        self._w_over_count = np.where(count > 0, self.w / np.maximum(count, 1), 0).astype(np.float32)
        self.x_inertial = self.delta = None

    @classmethod
    def from_scene(cls, scene, solver: str = "jacobi") -> "NumpyCloth":
        """The arrays of ``scene`` as the Warp simulator builds them (coloured stick order and stick weights;
        the colouring is only used by the coloured solver)."""
        from warp_verlet.core.simulator import Simulator

        if scene.colliders:
            raise ValueError("the numpy baseline has no colliders")
        settings = dataclasses.replace(scene.simulation, relaxation="coloured")
        sim = Simulator(dataclasses.replace(scene, simulation=settings), device="cpu")
        m = sim.model
        if m.compliant or m.tether_table is not None:
            raise ValueError("the numpy baseline has rigid sticks only: no compliance, no tethers")
        s = scene.simulation
        return cls(sim.positions(), m.inv_mass.numpy(), m.host_sticks, m.host_rest, m.stick_weight.numpy(),
                   m.colour_ranges, dt=s.dt, substeps=s.substeps, iterations=s.iterations, damping=s.damping,
                   accel=np.add(s.gravity, s.wind), solver=solver)

    # ------------------------------------------------------------------ Verlet
    def _accel_offset(self) -> np.ndarray:
        # Fixed dt: a * dt * (dt + dt_prev) / 2 = a dt^2, rounded once to float32 as the simulator does.
        return (self.accel.astype(np.float64) * (self.dt * self.dt)).astype(np.float32)

    def _verlet(self) -> None:
        if self.delta is None:  # exact start from rest: x_prev = x0 + a dt^2 / 2
            self.x_inertial = self.x.copy()
            half = np.float32(0.5) * np.float32(self.dt) * np.float32(self.dt)
            self.delta = np.where(self.free[:, None], -(self.accel * half), np.float32(0)).astype(np.float32)
        f = self.free
        step = (self.delta[f] + (self.x[f] - self.x_inertial[f])) * self.velocity_scale + self._accel_offset()
        self.x[f] += step
        self.x_inertial[f] = self.x[f]
        self.delta[f] = step

    # ------------------------------------------------------------------ relaxation
    def _correction(self, xa, xb, wa, wb, rest, k):
        """Per-unit-w move of end a for each stick (kernels/relax.py stick_correction, k the stick's weight),
        float32."""
        d = xb - xa
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        w = wa + wb
        ok = (w != 0) & (length >= MIN_LENGTH)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(ok, k * (length - rest) / (length * w), np.float32(0)).astype(np.float32)
        return d * s[:, None]

    def _jacobi_sweep(self) -> None:
        x, w = self.x, self.w
        c = self._correction(x[self.a], x[self.b], w[self.a], w[self.b], self.rest, self.k)
        # End a gains +c, end b gains -c (each then scaled by its own w / count).
        both = np.concatenate([c, -c])
        total = np.empty_like(x)
        for dim in range(3):
            total[:, dim] = np.bincount(self._ends, weights=both[:, dim], minlength=self.n)
        x += total * self._w_over_count[:, None]

    def _coloured_sweep(self) -> None:
        x, w = self.x, self.w
        for first, count in self.colour_ranges:
            a, b = self.a[first:first + count], self.b[first:first + count]
            wa, wb = w[a], w[b]
            c = self._correction(x[a], x[b], wa, wb, self.rest[first:first + count], self.k[first:first + count])
            x[a] += c * wa[:, None]  # no particle appears twice within a colour: plain fancy indexing is exact
            x[b] -= c * wb[:, None]

    def step(self) -> None:
        self._verlet()
        sweep = self._jacobi_sweep if self.solver == "jacobi" else self._coloured_sweep
        for _ in range(self.iterations):
            sweep()

    def step_frame(self) -> None:
        for _ in range(self.substeps):
            self.step()

    def positions(self) -> np.ndarray:
        return self.x.copy()


def measure(cloth: NumpyCloth, frames: int, repeats: int = 1) -> dict:
    """Median seconds per frame over ``repeats`` batches (after one warm-up frame), and projections/s."""
    times = time_frames(cloth, frames, repeats, warm_up=1)
    per_frame = float(np.median(times))
    return {"s_per_frame": per_frame, "min": min(times), "max": max(times),
            "proj_per_s": cloth.stick_count * cloth.substeps * cloth.iterations / per_frame}


def compare_with_warp(scene, solver: str, frames: int) -> dict:
    """Run the Warp CPU simulator and the numpy baseline ``frames`` frames from the same start; the largest
    and RMS particle distance, and both structural stretch figures."""
    from warp_verlet.core.simulator import Simulator

    scene = dataclasses.replace(scene, simulation=dataclasses.replace(scene.simulation, relaxation=solver))
    sim = Simulator(scene, device="cpu")
    ref = NumpyCloth.from_scene(scene, solver)
    for _ in range(frames):
        sim.step_frame()
        ref.step_frame()
    xw, xn = sim.positions().astype(np.float64), ref.positions().astype(np.float64)
    dist = np.linalg.norm(xw - xn, axis=1)
    sw, sn = sim.stretch(), sim.stretch(ref.positions())
    moved = np.linalg.norm(xw - sim.model.rest_positions, axis=1)
    return {"max_diff": float(dist.max()), "rms_diff": float(np.sqrt(np.mean(dist**2))),
            "max_moved": float(moved.max()), "stretch_rms_warp": sw.rms, "stretch_rms_numpy": sn.rms,
            "stretch_max_warp": sw.max, "stretch_max_numpy": sn.max}


def main(argv=None) -> int:
    p = arg_parser("bench.numpy_baseline", __doc__)
    p.add_argument("--size", type=int, default=64, help="grid n x n of the bench hanging cloth")
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--substeps", type=int, default=4)
    p.add_argument("--iterations", type=int, default=8)
    p.add_argument("--solver", choices=["jacobi", "coloured", "both"], default="both")
    p.add_argument("--check", action="store_true", help="compare positions with the Warp CPU simulator")
    args = p.parse_args(argv)
    quiet_warp()
    scene = hanging_cloth(args.size, args.substeps, args.iterations)
    for solver in (["jacobi", "coloured"] if args.solver == "both" else [args.solver]):
        r = measure(NumpyCloth.from_scene(scene, solver), args.frames, args.repeats)
        print(f"numpy {solver:8s} {args.size}x{args.size}, {args.substeps} x {args.iterations}: "
              f"{r['s_per_frame'] * 1e3:.1f} ms/frame ({r['min'] * 1e3:.1f}..{r['max'] * 1e3:.1f}), "
              f"{r['proj_per_s'] / 1e6:.2f} M projections/s", flush=True)
        if args.check:
            c = compare_with_warp(scene, solver, args.frames)
            print(f"  vs Warp after {args.frames} frames: max |dx| {c['max_diff']:.2e} m, rms {c['rms_diff']:.2e} m "
                  f"(largest displacement {c['max_moved']:.3f} m); stretch rms Warp {c['stretch_rms_warp']:.4e} "
                  f"numpy {c['stretch_rms_numpy']:.4e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
