"""Four integrators on the same problems: the textbook claims about Verlet integration, checked with numbers.

    python -m bench.integrators [--out bench/results/integrators] [--quick] [--no-plots]

Explicit Euler, semi-implicit (symplectic) Euler, position Verlet and classic RK4, in plain float64 numpy:

1. Undamped pendulum, theta'' = -(g/L) sin(theta), L = 1 m, g = 9.81, theta0 = 1 rad, 20 s at dt = 0.01.
2. A pinned chain: 5 point masses of 0.1 kg on 0.2 m linear springs of k = 2000 N/m, the top one pinned,
   released horizontal under gravity, 20 s at dt = 1 ms. The stiffest mode has omega ~ 2 sqrt(k/m) = 283 rad/s,
   so omega dt = 0.28: inside the stability limit of every method but explicit Euler, which has none.
3. Position error at T = 2 s of the pendulum against its exact (Jacobi elliptic) solution, over dt halving
   from 0.08 s; the log-log slope is the order. Cost is counted in force evaluations (1, 1, 1, 4 per step).

Energy drift is |E - E0| / (E0 - E_min): relative to the energy of motion (E_min is the resting state: the
pendulum at the bottom, the chain hanging still), since the chain's E0 has no natural zero.
Verlet keeps no velocity: x_{n+1} = 2 x_n - x_{n-1} + a dt^2 from x_{-1} = x0 - v0 dt + a0 dt^2 / 2, and its
energy uses the central difference (x_{n+1} - x_{n-1}) / (2 dt).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .common import arg_parser, markdown_table, write_csv

G, L, THETA0 = 9.81, 1.0, 1.0                    # pendulum
N_CHAIN, K_SPRING, MASS, REST = 5, 2000.0, 0.1, 0.2  # chain
METHODS = ["explicit_euler", "semi_implicit_euler", "verlet", "rk4"]
EVALS = {"explicit_euler": 1, "semi_implicit_euler": 1, "verlet": 1, "rk4": 4}
FIT_WINDOW = (1e-11, 1e-1)  # order fit uses errors inside this band: asymptotic, and above round-off


# ---------------------------------------------------------------- integrators

def simulate(method: str, accel, x0, v0, dt: float, steps: int):
    """Positions and velocities at steps + 1 times, shape (steps + 1, *x0.shape)."""
    x, v = np.array(x0, float), np.array(v0, float)
    xs, vs = np.empty((steps + 1, *x.shape)), np.empty((steps + 1, *x.shape))
    xs[0], vs[0] = x, v
    if method == "verlet":
        a = accel(x)
        prev = x - v * dt + 0.5 * a * dt * dt
        for n in range(steps + 1):          # one step past the end, for the last central difference
            nxt = 2 * x - prev + accel(x) * dt * dt
            vs[n] = (nxt - prev) / (2 * dt)
            if n < steps:
                xs[n + 1] = nxt
            prev, x = x, nxt
        return xs, vs
    for n in range(steps):
        if method == "explicit_euler":
            x, v = x + dt * v, v + dt * accel(x)
        elif method == "semi_implicit_euler":
            v = v + dt * accel(x)
            x = x + dt * v
        elif method == "rk4":
            k1x, k1v = v, accel(x)
            k2x, k2v = v + 0.5 * dt * k1v, accel(x + 0.5 * dt * k1x)
            k3x, k3v = v + 0.5 * dt * k2v, accel(x + 0.5 * dt * k2x)
            k4x, k4v = v + dt * k3v, accel(x + dt * k3x)
            x = x + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
            v = v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        else:
            raise ValueError(method)
        xs[n + 1], vs[n + 1] = x, v
    return xs, vs


# ---------------------------------------------------------------- problems

def pendulum_accel(theta):
    return -(G / L) * np.sin(theta)


def pendulum_energy(theta, omega):
    """Per unit mass, zero at the bottom: E_min = 0."""
    return 0.5 * (L * omega) ** 2 + G * L * (1 - np.cos(theta))


def pendulum_exact(t: float) -> float:
    """theta(t) released from rest at THETA0: 2 asin(k sn(K - w t | k^2)), k = sin(THETA0 / 2)."""
    k, w = np.sin(THETA0 / 2), np.sqrt(G / L)
    a, b, cs = [1.0], [np.sqrt(1 - k * k)], [k]        # arithmetic-geometric mean (A&S 16.4)
    while abs(cs[-1]) > 1e-16 * a[-1] and len(a) < 30:   # quadratic: about 5 rounds
        a.append((a[-1] + b[-1]) / 2)
        b.append(np.sqrt(a[-2] * b[-1]))
        cs.append((a[-2] - b[-2]) / 2)
    quarter = np.pi / (2 * a[-1])                      # K(k)
    phi = 2 ** (len(a) - 1) * a[-1] * (quarter - w * t)
    for n in range(len(a) - 1, 0, -1):
        phi = (phi + np.arcsin(cs[n] / a[n] * np.sin(phi))) / 2
    return 2 * np.arcsin(k * np.sin(phi))


def chain_accel(x):
    """x: (N, 2). Linear springs between neighbours, gravity along -y, particle 0 pinned."""
    d = x[1:] - x[:-1]
    length = np.linalg.norm(d, axis=1, keepdims=True)
    f = K_SPRING * (length - REST) * d / length        # pulls i towards i + 1
    force = np.zeros_like(x)
    force[:-1] += f
    force[1:] -= f
    a = force / MASS
    a[:, 1] -= G
    a[0] = 0.0
    return a


def chain_energy(xs, vs):
    """xs, vs: (T, N, 2) -> (T,). Kinetic + spring + gravity (height 0 at the pin)."""
    stretch = np.linalg.norm(xs[:, 1:] - xs[:, :-1], axis=2) - REST
    return (0.5 * MASS * (vs ** 2).sum(axis=(1, 2)) + 0.5 * K_SPRING * (stretch ** 2).sum(axis=1)
            + MASS * G * xs[:, 1:, 1].sum(axis=1))


def chain_start():
    x0 = np.zeros((N_CHAIN, 2))
    x0[:, 0] = REST * np.arange(N_CHAIN)
    return x0, np.zeros_like(x0)


def chain_rest_energy() -> float:
    """The chain hanging still: spring j carries the weight of the particles below it."""
    y, energy = 0.0, 0.0
    for j in range(1, N_CHAIN):
        ext = (N_CHAIN - j) * MASS * G / K_SPRING
        y -= REST + ext
        energy += 0.5 * K_SPRING * ext ** 2 + MASS * G * y
    return energy


# ---------------------------------------------------------------- measurements

def drift_stats(energy, e0: float, scale: float) -> dict:
    rel = (energy - e0) / scale
    quarters = np.array_split(rel, 4)
    finite, doubled = np.isfinite(rel), np.abs(rel) > 1
    return {"rel": rel, "max": float(np.max(np.abs(rel))) if finite.all() else float("inf"),
            "final": float(rel[-1]),
            "first_quarter_max": float(np.max(np.abs(quarters[0]))),
            "last_quarter_max": float(np.max(np.abs(quarters[-1]))),
            "quarter_means": [float(np.mean(q)) for q in quarters],     # signed: a trend shows as a ramp
            "doubled_at": int(np.argmax(doubled)) if doubled.any() else None,   # first step with |E - E0| > scale
            "diverged_at": None if finite.all() else int(np.argmin(finite))}


def fit_order(dts, errors) -> tuple[float, int]:
    """Least-squares log-log slope over the errors inside FIT_WINDOW; and how many points it used."""
    dts, errors = np.asarray(dts), np.asarray(errors)
    use = (errors > FIT_WINDOW[0]) & (errors < FIT_WINDOW[1])
    if use.sum() < 2:
        return float("nan"), int(use.sum())
    return float(np.polyfit(np.log(dts[use]), np.log(errors[use]), 1)[0]), int(use.sum())


def run(quick: bool = False) -> dict:
    """Every measurement, per method; arrays of energy over time included for the plots."""
    out = {"pendulum": {}, "chain": {}, "convergence": {}, "summary": {}}
    # 1. pendulum energy (same dt and length in quick mode: it is cheap, and the claims are made at dt = 0.01)
    dt_p, t_p = 0.01, 20.0
    steps = round(t_p / dt_p)
    e0 = pendulum_energy(THETA0, 0.0)
    out["pendulum"]["t"] = np.arange(steps + 1) * dt_p
    for m in METHODS:
        th, om = simulate(m, pendulum_accel, np.array([THETA0]), np.array([0.0]), dt_p, steps)
        out["pendulum"][m] = drift_stats(pendulum_energy(th[:, 0], om[:, 0]), e0, e0)
    # 2. chain energy
    dt_c, t_c = 1e-3, (0.5 if quick else 20.0)
    steps = round(t_c / dt_c)
    x0, v0 = chain_start()
    e0 = chain_energy(x0[None], v0[None])[0]
    scale = e0 - chain_rest_energy()
    out["chain"]["t"] = np.arange(steps + 1) * dt_c
    with np.errstate(over="ignore", invalid="ignore"):
        for m in METHODS:
            xs, vs = simulate(m, chain_accel, x0, v0, dt_c, steps)
            out["chain"][m] = drift_stats(chain_energy(xs, vs), e0, scale)
    # 3. error at T = 2 s against the exact pendulum; dt = 2 / (25 * 2^k), so dt = 0.01 is always in the sweep
    t_end, ks = 2.0, (range(2, 8) if quick else range(0, 11))
    exact = pendulum_exact(t_end)
    for m in METHODS:
        rows = []
        for k in ks:
            n = 25 * 2 ** k
            th, _ = simulate(m, pendulum_accel, np.array([THETA0]), np.array([0.0]), t_end / n, n)
            rows.append({"dt": t_end / n, "steps": n, "force_evals": EVALS[m] * n,
                         "error": float(abs(th[-1, 0] - exact))})
        out["convergence"][m] = rows
        order, used = fit_order([r["dt"] for r in rows], [r["error"] for r in rows])
        at_ref = next(r["error"] for r in rows if abs(r["dt"] - 0.01) < 1e-12)
        out["summary"][m] = {
            "integrator": m, "force_evals_per_step": EVALS[m],
            "pendulum_drift_max": out["pendulum"][m]["max"], "pendulum_drift_final": out["pendulum"][m]["final"],
            "chain_drift_max": out["chain"][m]["max"], "chain_drift_final": out["chain"][m]["final"],
            "fitted_order": order, "fit_points": used, "error_at_dt_0.01": at_ref}
    out["settings"] = {"pendulum": f"dt={dt_p}, T={t_p} s", "chain": f"dt={dt_c}, T={t_c} s",
                       "convergence": f"T={t_end} s, dt=2/(25*2^k), k={ks.start}..{ks.stop - 1}"}
    return out


# ---------------------------------------------------------------- output

def fmt(v) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def markdown(res: dict) -> str:
    s = res["settings"]
    keys = list(res["summary"]["rk4"])
    lines = [f"### Integrators: pendulum ({s['pendulum']}), chain ({s['chain']}), convergence ({s['convergence']})",
             "", "Drift = |E - E0| / (E0 - E_min), max over the run; final is signed (E - E0) / (E0 - E_min). "
             "Order = log-log slope of the T = 2 s pendulum position error over the errors in "
             f"[{FIT_WINDOW[0]:g}, {FIT_WINDOW[1]:g}].", "",
             markdown_table([{k: fmt(r[k]) for k in keys} for r in res["summary"].values()]), "",
             "Mean signed (E - E0) / (E0 - E_min) over each quarter of the run (a ramp is secular drift):", "",
             markdown_table([{"integrator": m, "problem": problem,
                              **{f"Q{i}": fmt(v) for i, v in enumerate(res[problem][m]["quarter_means"], 1)}}
                             for problem in ("pendulum", "chain") for m in METHODS])]
    notes = []
    for problem in ("pendulum", "chain"):
        t = res[problem]["t"]
        for m in METHODS:
            d = res[problem][m]
            if d["doubled_at"] is not None:
                end = "." if d["diverged_at"] is None else f", non-finite from t = {t[d['diverged_at']]:.3f} s."
                notes.append(f"{m} on the {problem}: |E - E0| passed E0 - E_min at t = {t[d['doubled_at']]:.3f} s"
                             + end)
    return "\n".join(lines + [""] + notes) + "\n"


def write_outputs(res: dict, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "summary.csv", out / "convergence.csv", out / "energy_pendulum.csv", out / "energy_chain.csv",
             out / "integrators.md"]
    write_csv(files[0], list(res["summary"].values()))
    write_csv(files[1], [{"integrator": m, **r} for m in METHODS for r in res["convergence"][m]])
    for path, problem in ((files[2], "pendulum"), (files[3], "chain")):
        stride = max(len(res[problem]["t"]) // 2000, 1)      # at most ~2000 rows; the plots use every step
        cols = np.column_stack([res[problem]["t"]] + [res[problem][m]["rel"] for m in METHODS])[::stride]
        np.savetxt(path, cols, delimiter=",", header="t," + ",".join(METHODS), comments="", fmt="%.10g")
    files[4].write_text(markdown(res))
    return files


def plot(res: dict, out: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = dict(zip(METHODS, ["tab:red", "tab:orange", "tab:blue", "tab:green"]))
    files = []
    for problem, title in (("pendulum", "Pendulum, theta0 = 1 rad"), ("chain", "Pinned spring chain, k = 2000 N/m")):
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
        t = res[problem]["t"]
        for m in METHODS:
            rel = res[problem][m]["rel"]
            top.plot(t, 1 + rel, color=colours[m], label=m)
            bottom.semilogy(t, np.clip(np.abs(rel), 1e-17, 1e30), color=colours[m], lw=0.8, label=m)
        top.set_ylim(0.5, 4.0)
        bottom.set_ylim(1e-12, 1e4)
        top.set_ylabel("(E - E_min) / (E0 - E_min)")
        top.set_title(f"{title}: energy ({res['settings'][problem]})")
        top.legend(loc="upper left")
        bottom.set_ylabel("|E - E0| / (E0 - E_min)")
        bottom.set_xlabel("t [s]")
        bottom.grid(True, which="major", alpha=0.3)
        fig.tight_layout()
        files.append(out / f"energy_{problem}.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
    for xkey, xlabel, stem in (("dt", "time step dt [s]", "error_vs_dt"),
                               ("force_evals", "force evaluations (cost)", "error_vs_evals")):
        fig, ax = plt.subplots(figsize=(7, 5))
        for m in METHODS:
            rows = res["convergence"][m]
            x, err = np.array([r[xkey] for r in rows]), np.array([r["error"] for r in rows])
            order = res["summary"][m]["fitted_order"]
            slope = order if xkey == "dt" else -order
            used = (err > FIT_WINDOW[0]) & (err < FIT_WINDOW[1])
            ax.loglog(x, err, "o-", color=colours[m], mfc="none")
            ax.loglog(x[used], err[used], "o", color=colours[m], label=f"{m} (fitted slope {slope:.2f})")
        ax.axhspan(1e-20, FIT_WINDOW[0], color="grey", alpha=0.15, label="outside fit window (hollow points)")
        ax.axhspan(FIT_WINDOW[1], 1e3, color="grey", alpha=0.15)
        ax.set_ylim(1e-16, 10)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("|theta(T) - theta_exact(T)| [rad], T = 2 s")
        ax.set_title(f"Pendulum, theta0 = 1 rad: position error at T = 2 s vs {xlabel.split(' [')[0]}")
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        files.append(out / f"{stem}.png")
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
    return files


def main(argv=None) -> int:
    p = arg_parser("bench.integrators", __doc__)
    p.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "integrators")
    p.add_argument("--quick", action="store_true", help="short runs and few dt values (smoke test)")
    p.add_argument("--no-plots", action="store_true")
    args = p.parse_args(argv)
    res = run(args.quick)
    print(markdown(res))
    files = write_outputs(res, args.out)
    if not args.no_plots:
        files += plot(res, args.out)
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
