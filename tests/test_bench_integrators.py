"""bench.integrators: the seed article's integrator claims, checked on its quick-mode numbers.

Pendulum: theta0 = 1 rad, dt = 0.01, 20 s. Chain: 5 masses, k = 2000 N/m, dt = 1 ms, 0.5 s in quick mode.
Drift is (E - E0) / (E0 - E_min). Bounds are set from measured values (in each comment) with a margin.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import bench_package  # noqa: F401  (makes the repository's bench/ importable as the package "bench")
from bench import integrators


@pytest.fixture(scope="module")
def res():
    return integrators.run(quick=True)


@pytest.mark.slow
def test_cli_quick_writes_outputs(tmp_path):
    assert integrators.main(["--quick", "--out", str(tmp_path)]) == 0
    for name in ("summary.csv", "convergence.csv", "energy_pendulum.csv", "energy_chain.csv", "integrators.md",
                 "energy_pendulum.png", "energy_chain.png", "error_vs_dt.png", "error_vs_evals.png"):
        assert (tmp_path / name).stat().st_size > 0, name
    with open(tmp_path / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["integrator"] for r in rows] == integrators.METHODS
    assert list(rows[0]) == ["integrator", "force_evals_per_step", "pendulum_drift_max", "pendulum_drift_final",
                             "chain_drift_max", "chain_drift_final", "fitted_order", "fit_points", "error_at_dt_0.01"]
    for r in rows:
        assert all(math.isfinite(float(v)) for k, v in r.items() if k != "integrator"), r  # quick mode: all finite
    with open(tmp_path / "convergence.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["integrator", "dt", "steps", "force_evals", "error"]
    assert len(rows) == 4 * 6 and all(math.isfinite(float(r["error"])) for r in rows)
    for name in ("energy_pendulum.csv", "energy_chain.csv"):
        data = np.genfromtxt(tmp_path / name, delimiter=",", names=True)
        assert list(data.dtype.names) == ["t"] + integrators.METHODS
        assert all(np.isfinite(data[c]).all() for c in data.dtype.names)


def test_exact_pendulum_reference():
    # The elliptic-function solution starts at theta0 (to 1e-14) and matches RK4 at dt = 5e-4 over 2 s
    # to 1e-12 (measured 8e-14; RK4's own error there is ~1e-13).
    assert abs(integrators.pendulum_exact(0.0) - integrators.THETA0) < 1e-14
    th, _ = integrators.simulate("rk4", integrators.pendulum_accel, np.array([integrators.THETA0]), np.array([0.0]),
                                 5e-4, 4000)
    assert abs(th[-1, 0] - integrators.pendulum_exact(2.0)) < 1e-12


def test_verlet_exact_start_integrates_constant_acceleration_exactly():
    # x_{-1} = x0 - v0 dt + a dt^2 / 2 makes free fall exact up to round-off: within 1e-11 after 100 steps
    # (measured 3e-13 m and 5e-13 m/s; the x_prev form's round-off grows with steps^2).
    xs, vs = integrators.simulate("verlet", lambda x: np.full_like(x, -9.81), np.array([1.0]), np.array([2.0]), 0.01,
                                  100)
    t = np.arange(101) * 0.01
    assert np.max(np.abs(xs[:, 0] - (1 + 2 * t - 0.5 * 9.81 * t**2))) < 1e-11
    assert np.max(np.abs(vs[:, 0] - (2 - 9.81 * t))) < 1e-11  # central difference is exact for a parabola


def test_fitted_orders(res):
    # Fitted log-log slopes within +-0.3 of 1, 1, 2, 4 (measured 1.00, 1.00, 2.00, 4.05), from at least 3 points.
    for method, order in zip(integrators.METHODS, (1, 1, 2, 4)):
        s = res["summary"][method]
        assert abs(s["fitted_order"] - order) < 0.3, (method, s["fitted_order"])
        assert s["fit_points"] >= 3, method


def test_explicit_euler_gains_energy(res):
    p = res["pendulum"]["explicit_euler"]
    assert p["final"] > 1.0          # E(20 s) > 2 E0 (measured E = 3.66 E0)
    assert np.all(np.diff(p["quarter_means"]) > 0)                  # rises every quarter (0.23, 0.80, 1.50, 2.26)
    assert p["last_quarter_max"] > 3 * p["first_quarter_max"]        # secular growth (measured 5.4x)
    assert res["chain"]["explicit_euler"]["max"] > 10   # chain after 0.5 s: |E - E0| > 10 (E0 - E_min); measured 173


@pytest.mark.parametrize("method, band", [("semi_implicit_euler", 0.02), ("verlet", 1e-3)])
def test_symplectic_energy_bounded(res, method, band):
    p = res["pendulum"][method]
    # Pendulum at dt = 0.01: |E - E0| / E0 < 2% for semi-implicit Euler (measured 1.50%), < 0.1% for Verlet (0.023%).
    assert p["max"] < band
    # No secular growth: the last quarter's max within 10% of the first's (measured ratio 1.000 for both).
    assert p["last_quarter_max"] < 1.1 * p["first_quarter_max"]
    # Chain, 0.5 s at dt = 1 ms: < 1% (measured 0.17% semi-implicit, 0.002% Verlet).
    assert res["chain"][method]["max"] < 0.01


def test_rk4_accurate_but_dissipative(res):
    p = res["pendulum"]["rk4"]
    assert p["max"] < 1e-7                          # measured 2.0e-8: far below the others
    assert p["final"] < 0                           # it loses energy...
    assert np.all(np.diff(p["quarter_means"]) < 0)  # ...steadily (quarter means -2.9e-9, -7.7e-9, -1.2e-8, -1.7e-8)
    assert res["chain"]["rk4"]["max"] < 1e-6        # chain after 0.5 s: measured 6.0e-8


def test_rk4_smallest_error_at_equal_dt(res):
    conv = res["convergence"]
    for i, row in enumerate(conv["rk4"]):
        others = [conv[m][i]["error"] for m in integrators.METHODS if m != "rk4"]
        assert row["error"] < min(others), row  # at every dt of the sweep (by 6000x at dt = 0.01)
    # and the expected ranking at dt = 0.01: Verlet 8.3e-5 < semi-implicit 5.7e-3 < explicit 7.2e-2
    err = {m: res["summary"][m]["error_at_dt_0.01"] for m in integrators.METHODS}
    assert err["rk4"] < err["verlet"] < err["semi_implicit_euler"] < err["explicit_euler"]
