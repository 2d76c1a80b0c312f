"""A global correction with contact inside it, prototyped on the host: how far can it take the drape?

    python -m bench.global_step [--sizes 64 ...] [--budgets SxK ...] [--linear direct amg:N jacobi:N bilinear:F agg:F ...]
        [--newton 1 2 ...] [--friction 0 0.5 ...] [--frames 90] [--out DIR]

The drape of ``bench.convergence`` (1 m, 0.2 kg, structural + shear + bend sticks, dropped from 0.5 m onto a
0.25 m sphere, ground at -0.5 m, read at 1.5 s) runs through the real simulator on the CPU (one relaxation
thread), with one extra stage between the Verlet prediction and the sweeps: ``newton`` Gauss-Newton steps on

    E(x) = 1/2 (x - x~)^T M/h^2 (x - x~) + 1/2 k sum_sticks (|x_i - x_j| - L)^2 + 1/2 kc sum_contacts min(0, phi(x))^2

from the prediction x~, the sticks as stiff springs (k = STIFFNESS x m/h^2 of a particle: rigid to the step's
resolution) and each contact a push-only normal penalty (kc = CONTACT x the particle's diagonal; a particle is
in the active set when the prediction puts it inside a collider). Each step solves H dx = -grad E with the
Gauss-Newton matrix H = M/h^2 + k J^T J + kc n n^T:

- ``direct``: a sparse LU (SciPy), the exact step: what any preconditioned Krylov solve converges to;
- ``amg:N``: N conjugate-gradient iterations preconditioned by a smoothed-aggregation AMG V-cycle (PyAMG),
  the kind of operator hierarchy a device implementation would use;
- ``jacobi:N``: N conjugate-gradient iterations preconditioned by the diagonal, the cheapest global step;
- ``bilinear:F[:J]`` and ``agg:F``: a coarse correction alone, no fine solve: the Galerkin system P^T H P of a grid
  of every F-th particle (bilinear interpolation) or of F x F aggregates, solved exactly, then J damped-Jacobi
  sweeps (bench/results/global_solve.md: it throws the cloth).

The dual form, ``dual:SOLVER`` (Goldenthal et al. 2007, "fast projection"; Li et al. 2025, MGPBD), takes
``newton`` Newton steps on the constraint manifold instead, from the prediction clamped to the colliders: with
C(x) = |x_i - x_j| - L per stick and its Jacobian J,

    (J W J^T + alpha) dlambda = -C - alpha lambda,    x += W J^T dlambda,    lambda += dlambda

(lambda zero at the substep's start), W each particle's inverse mass, times (I - n n^T) for a particle on a collider
(normal n: it may slide along the surface, not move through or off it within the step; the clamp after the step
lets it leave). The three families of rigid sticks over-constrain a grid (about six sticks a particle, three
degrees of freedom), so J W J^T is singular and alpha = ``DUAL_REGULARISATION`` x its diagonal makes each step a
damped least-squares one (MGPBD needs compliance > 0 for the same reason). SOLVER is ``direct``, ``amg:N`` or
``jacobi:N`` on that system.

``--friction mu`` gives the ball Coulomb friction (``friction_coefficient``): a frictionless ball lets a converged
drape slide off it to the ground, so that a low stretch can mean a cloth that lies flat; top y tells.

After the step every collider clamps, then the coloured sweeps make the final projection and the substep's
clamp runs, exactly as without the stage. Rows give the final RMS and max structural stretch, the lowest
particle and the host time (a prototype's, not a device figure). ``none`` is the plain simulator.

This is a host prototype to choose a device method: it is not part of the package (SciPy and PyAMG are bench
dependencies only: ``pip install scipy pyamg``).
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np

STIFFNESS = 1.0e4  # k h^2 / m: sticks 1e4 x stiffer than a particle's inertia over one substep
CONTACT = 1.0e2  # contact penalty per unit of the particle's own diagonal
DUAL_REGULARISATION = 1.0e-2  # the dual step's alpha per unit of its system's diagonal
ON_SURFACE = 1.0e-7  # m: a particle closer than this to a collider's surface after the clamp is in contact


def _need(module: str):
    try:
        return __import__(module)
    except ImportError:
        sys.exit(f"bench.global_step needs {module} (pip install scipy pyamg)")


class GlobalStep:
    """The stage: Gauss-Newton steps with the contact penalty, solved by ``linear``."""

    def __init__(self, model, sphere: tuple[np.ndarray, float], ground_y: float, linear: str, newton: int):
        _need("scipy")
        import scipy.sparse as sp
        import scipy.sparse.linalg as spla

        self.sp, self.spla = sp, spla
        self.ends = np.asarray(model.host_sticks, np.int64)
        self.rest = np.asarray(model.host_rest, np.float64)
        w = np.asarray(model.host_inv_mass, np.float64)
        self.free = w > 0
        self.mass = np.where(self.free, 1.0 / np.where(self.free, w, 1.0), 0.0)
        self.n = len(w)
        self.centre, self.radius = sphere
        self.ground_y = ground_y
        self.linear, self.newton = linear, newton
        s = len(self.ends)
        self.cg_iterations = 0
        self.solves = 0
        # J's sparsity: row s has -n at particle i's 3 columns and +n at j's
        self._j_rows = np.repeat(np.arange(s), 6)
        cols = np.concatenate([3 * self.ends[:, :1] + np.arange(3), 3 * self.ends[:, 1:] + np.arange(3)], axis=1)
        self._j_cols = cols.ravel()

    def contacts(self, x: np.ndarray, within: float = 0.0):
        """(index, normal, signed distance) of each particle inside a collider, or less than ``within`` (m) outside
        it (sphere first, then ground)."""
        d = x - self.centre
        r = np.linalg.norm(d, axis=1)
        inside = (r < self.radius + within) & self.free
        idx = [np.nonzero(inside)[0]]
        nrm = [d[inside] / r[inside, None]]
        phi = [r[inside] - self.radius]
        g = (x[:, 1] < self.ground_y + within) & self.free
        idx.append(np.nonzero(g)[0])
        nrm.append(np.tile([0.0, 1.0, 0.0], (int(g.sum()), 1)))
        phi.append(x[g, 1] - self.ground_y)
        return np.concatenate(idx), np.concatenate(nrm), np.concatenate(phi)

    def clamp(self, x: np.ndarray) -> None:
        d = x - self.centre
        r = np.linalg.norm(d, axis=1)
        inside = (r < self.radius) & self.free
        x[inside] = self.centre + d[inside] * (self.radius / r[inside, None])
        g = (x[:, 1] < self.ground_y) & self.free
        x[g, 1] = self.ground_y

    def __call__(self, x: np.ndarray, x_pred: np.ndarray, h: float) -> np.ndarray:
        sp = self.sp
        m_h2 = self.mass / (h * h)
        k = STIFFNESS * float(m_h2[self.free].mean())
        for _ in range(self.newton):
            a, b = self.ends[:, 0], self.ends[:, 1]
            d = x[b] - x[a]
            length = np.linalg.norm(d, axis=1)
            nrm = d / np.maximum(length, 1e-12)[:, None]
            c = length - self.rest
            # gradient
            grad = (m_h2[:, None] * (x - x_pred))
            f = (k * c)[:, None] * nrm
            np.add.at(grad, a, -f)
            np.add.at(grad, b, f)
            jv = np.concatenate([-nrm, nrm], axis=1).ravel()
            J = sp.csr_matrix((jv, (self._j_rows, self._j_cols)), shape=(len(self.ends), 3 * self.n))
            H = (J.T @ J) * k + sp.diags(np.repeat(np.where(self.free, m_h2, 1.0), 3))
            idx, cn, phi = self.contacts(x)
            if len(idx):
                diag = H.diagonal().reshape(-1, 3)[idx].max(axis=1)
                kc = CONTACT * diag
                grad[idx] += (kc * phi)[:, None] * cn
                blocks = kc[:, None, None] * cn[:, :, None] * cn[:, None, :]
                r = (3 * idx[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
                cc = (3 * idx[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
                H = H + sp.csr_matrix((blocks.ravel(), (r.ravel(), cc.ravel())), shape=H.shape)
            grad[~self.free] = 0.0
            fixed = np.repeat(~self.free, 3)
            if fixed.any():  # pins: identity rows, zero right-hand side
                keep = sp.diags((~fixed).astype(float))
                H = keep @ H @ keep + sp.diags(fixed.astype(float))
            rhs = -grad.ravel()
            dx = self.solve(H.tocsr(), rhs)
            x = x + dx.reshape(-1, 3)
            self.clamp(x)
        return x

    def prolongation(self, kind: str, factor: int):
        """The grid's prolongation for all three components (particle r * side + c, component-major in 3s)."""
        cache = self.__dict__.setdefault("_prolongations", {})
        if (kind, factor) not in cache:
            side = int(round(np.sqrt(self.n)))
            P1 = self.sp.csr_matrix(axis_prolongation(side, kind, factor))
            cache[kind, factor] = self.sp.kron(self.sp.kron(P1, P1), self.sp.identity(3)).tocsr()
        return cache[kind, factor]

    def solve(self, H, rhs, dual: bool = False):
        self.solves += 1
        kind, _, count = self.linear.removeprefix("dual:").partition(":")
        if kind == "direct":
            return self.spla.spsolve(H.tocsc(), rhs)
        if kind in ("agg", "bilinear"):
            # A two-level correction alone: the Galerkin coarse system P^T H P of a grid every ``factor`` particles
            # (piecewise-constant aggregates, or bilinear interpolation), solved exactly, then ``smooth`` damped
            # Jacobi sweeps on the fine level.
            factor, _, smooth = count.partition(":")
            P = self.prolongation(kind, int(factor))
            coarse = (P.T @ H @ P).tocsc()
            dx = P @ self.spla.spsolve(coarse, P.T @ rhs)
            inv_diag = 1.0 / H.diagonal()
            for _ in range(int(smooth or 0)):
                dx = dx + 0.6 * inv_diag * (rhs - H @ dx)
            return dx
        iters = int(count or 20)
        if kind == "amg":
            pyamg = _need("pyamg")
            near_null = np.ones((H.shape[0], 1)) if dual else np.kron(np.ones((self.n, 1)), np.eye(3))
            ml = pyamg.smoothed_aggregation_solver(H, B=near_null, max_coarse=64)
            M = ml.aspreconditioner(cycle="V")
        elif kind == "jacobi":
            M = self.sp.diags(1.0 / H.diagonal())
        else:
            raise ValueError(f"unknown linear solver {self.linear!r}")
        dx, _ = self.spla.cg(H, rhs, M=M, maxiter=iters, rtol=1e-10)
        self.cg_iterations += iters
        return dx


class DualStep(GlobalStep):
    """The dual form: Newton steps on the sticks' lengths with the contacts filtered out of W (module docstring)."""

    def __call__(self, x: np.ndarray, x_pred: np.ndarray, h: float) -> np.ndarray:
        sp = self.sp
        w = np.where(self.free, 1.0 / np.where(self.free, self.mass, 1.0), 0.0)
        x = x.copy()
        self.clamp(x)
        lam = np.zeros(len(self.ends))
        a, b = self.ends[:, 0], self.ends[:, 1]
        for _ in range(self.newton):
            d = x[b] - x[a]
            length = np.linalg.norm(d, axis=1)
            nrm = d / np.maximum(length, 1e-12)[:, None]
            c = length - self.rest
            blocks = w[:, None, None] * np.eye(3)[None]
            idx, cn, _ = self.contacts(x, ON_SURFACE)  # on a collider's surface, after the clamp
            blocks[idx] -= w[idx, None, None] * cn[:, :, None] * cn[:, None, :]
            rows = (3 * np.arange(self.n)[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
            cols = (3 * np.arange(self.n)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
            W = sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * self.n, 3 * self.n))
            jv = np.concatenate([-nrm, nrm], axis=1).ravel()
            J = sp.csr_matrix((jv, (self._j_rows, self._j_cols)), shape=(len(self.ends), 3 * self.n))
            WJt = (W @ J.T).tocsc()
            A = (J @ WJt).tocsr()
            alpha = DUAL_REGULARISATION * A.diagonal()
            A = A + sp.diags(alpha)
            dlam = self.solve(A.tocsr(), -c - alpha * lam, dual=True)
            lam += dlam
            x = x + (WJt @ dlam).reshape(-1, 3)
            self.clamp(x)
        return x


def axis_prolongation(side: int, kind: str, factor: int) -> np.ndarray:
    """(side, coarse) weights of one grid axis: aggregates of ``factor`` particles, or linear interpolation between
    every ``factor``-th particle (and the last)."""
    if kind == "agg":
        coarse = -(-side // factor)
        P = np.zeros((side, coarse))
        P[np.arange(side), np.arange(side) // factor] = 1.0
        return P
    nodes = np.r_[np.arange(0, side - 1, factor), side - 1]
    P = np.zeros((side, len(nodes)))
    for i in range(side):
        k = min(np.searchsorted(nodes, i, side="right") - 1, len(nodes) - 2)
        t = (i - nodes[k]) / (nodes[k + 1] - nodes[k])
        P[i, k], P[i, k + 1] = 1.0 - t, t
    return P


def run_drape(n: int, substeps: int, iterations: int, linear: str, newton: int, frames: int = 90,
              contact_projection: str = "after_sweeps", friction: float = 0.0) -> dict:
    import warp as wp

    from bench.convergence import merge, scene_tables
    from warp_verlet.input.scene import parse_scene
    from warp_verlet.core.simulator import Simulator

    wp.config.quiet = True
    tables = scene_tables("drape", n, "plain", substeps, iterations, frames)
    tables = merge(tables, {"simulation": {"precision": "float64", "contact_projection": contact_projection}})
    if friction:
        tables["collider"][0]["friction_coefficient"] = friction
    scene = parse_scene(tables, file=f"<drape {n}>")
    # A host stage must run every substep: a captured frame would replay only the kernels.
    sim = Simulator(scene, "cpu", threads=1, use_graph=linear == "none")
    step = None
    if linear != "none":
        form = DualStep if linear.startswith("dual:") else GlobalStep
        step = form(sim.model, (np.zeros(3), 0.25), -0.5, linear, newton)
        solver = sim.solver
        original = solver.bind

        def bind(state):
            stages = original(state)
            out = []
            for name, run in stages:
                out.append((name, run))
                if name == "integrate":
                    def global_run(state, dt):
                        x = state.particle_q.numpy().astype(np.float64)
                        x_new = step(x.copy(), x, dt)
                        state.particle_q.assign(x_new.astype(state.particle_q.numpy().dtype))
                    out.append(("global", global_run))
            return out

        solver.bind = bind
    start = time.perf_counter()
    for _ in range(frames):
        sim.step_frame()
    wall = time.perf_counter() - start
    x = sim.positions()
    s = sim.stretch(x)
    sim.close()
    return {"n": n, "budget": f"{substeps}x{iterations}", "linear": linear, "newton": newton if step else 0,
            "friction": friction,
            "contact": contact_projection, "rms": s.rms, "max": s.max, "lowest_y": float(x[:, 1].min()),
            "top_y": float(x[:, 1].max()), "host_ms_per_frame": wall / frames * 1e3,
            "cg_per_substep": (step.cg_iterations / max(step.solves, 1) * newton) if step else 0}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", type=int, nargs="*", default=[64])
    p.add_argument("--budgets", nargs="*", default=["16x2"])
    p.add_argument("--linear", nargs="*", default=["none", "direct"])
    p.add_argument("--newton", type=int, nargs="*", default=[1])
    p.add_argument("--contact", nargs="*", default=["after_sweeps"])
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--friction", type=float, nargs="*", default=[0.0], help="the ball's friction_coefficient")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    lines = ["| grid | S × K | ball μ | contact | global step | Newton | RMS | max | lowest y (m) | top y (m) | "
             "host ms/frame |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for n in args.sizes:
        for budget in args.budgets:
            s, k = (int(v) for v in budget.split("x"))
            for mu, contact, linear in itertools.product(args.friction, args.contact, args.linear):
                for newton in (args.newton if linear != "none" else [0]):
                    r = run_drape(n, s, k, linear, newton, args.frames, contact, mu)
                    line = (f"| {n}² | {s} × {k} | {mu:g} | {contact} | {linear} | {r['newton']} | {r['rms']:.3%} | "
                            f"{r['max']:.2%} | {r['lowest_y']:.3f} | {r['top_y']:.3f} | {r['host_ms_per_frame']:.0f} |")
                    lines.append(line)
                    print(line, flush=True)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "global_step.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
