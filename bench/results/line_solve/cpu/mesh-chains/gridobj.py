import sys, numpy as np
n = int(sys.argv[1]); out = sys.argv[2]; jitter = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
h = 1.0 / (n - 1)
xs, zs = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(-0.5, 0.5, n))
P = np.c_[xs.ravel(), np.zeros(n * n), zs.ravel()]
rng = np.random.default_rng(0)
if jitter:
    inner = (np.abs(P[:, 0]) < 0.5 - 1e-9) & (np.abs(P[:, 2]) < 0.5 - 1e-9)
    P[inner, 0] += rng.uniform(-jitter, jitter, inner.sum()) * h
    P[inner, 2] += rng.uniform(-jitter, jitter, inner.sum()) * h
F = []
for r in range(n - 1):
    for c in range(n - 1):
        a, b, d, e = r * n + c, r * n + c + 1, (r + 1) * n + c, (r + 1) * n + c + 1
        F += [(a, d, e), (a, e, b)] if (not jitter or (r + c) % 2 == 0) else [(a, d, b), (b, d, e)]
with open(out, "w") as f:
    for p in P: f.write(f"v {p[0]:.9f} {p[1]:.9f} {p[2]:.9f}\n")
    for t in F: f.write(f"f {t[0]+1} {t[1]+1} {t[2]+1}\n")
