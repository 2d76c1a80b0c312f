"""Microbenchmark: the fused Verlet step with the tether pass, with the tether table as it is and compacted."""
import sys, time
import numpy as np
import warp as wp
from warp_verlet.kernels.integrate import implicit_move, verlet_step_tethered, verlet_step
from warp_verlet.kernels.positions import instance

wp.init()
dev = sys.argv[1] if len(sys.argv) > 1 else "cuda"
n_side = int(sys.argv[2]) if len(sys.argv) > 2 else 1024
N = n_side * n_side
K = 2


@wp.func
def tethered_rows(xp: wp.vec3, x: wp.array(dtype=wp.vec3), pin: wp.array2d(dtype=int), length: wp.array2d(dtype=float), t: int):
    k = int(0)
    while k < pin.shape[1]:
        a = pin[t, k]
        if a >= 0:
            d = xp - x[a]
            distance = wp.length(d)
            limit = length[t, k]
            if distance > limit:
                xp = x[a] + d * (limit / distance)
        k += 1
    return xp


@wp.kernel
def step_all_rows(x: wp.array(dtype=wp.vec3), x_inertial: wp.array(dtype=wp.vec3), delta: wp.array(dtype=wp.vec3),
                  velocity_scale: float, accel_offset: wp.vec3, pin: wp.array2d(dtype=int), length: wp.array2d(dtype=float)):
    i = wp.tid()
    if length[i, 0] < 0.0:
        return  # a pin
    step = (delta[i] + (x[i] - x_inertial[i])) * velocity_scale + accel_offset
    xi = x[i] + step
    x_inertial[i] = xi
    delta[i] = step
    x[i] = tethered_rows(xi, x, pin, length, i)


@wp.kernel
def step_slots(x: wp.array(dtype=wp.vec3), x_inertial: wp.array(dtype=wp.vec3), delta: wp.array(dtype=wp.vec3),
               velocity_scale: float, accel_offset: wp.vec3, slot: wp.array2d(dtype=wp.uint16),
               pin_particle: wp.array(dtype=int), length: wp.array2d(dtype=float)):
    i = wp.tid()
    if length[i, 0] < 0.0:
        return
    step = (delta[i] + (x[i] - x_inertial[i])) * velocity_scale + accel_offset
    xi = x[i] + step
    x_inertial[i] = xi
    delta[i] = step
    k = int(0)
    while k < 2:
        s = int(slot[i, k])
        if s < pin_particle.shape[0]:
            a = pin_particle[s]
            d = xi - x[a]
            distance = wp.length(d)
            limit = length[i, k]
            if distance > limit:
                xi = x[a] + d * (limit / distance)
        k += 1
    x[i] = xi


rng = np.random.default_rng(0)
g = np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij"), -1).reshape(-1, 2) / (n_side - 1)
pos = np.zeros((N, 3), np.float32); pos[:, 0] = g[:, 1]; pos[:, 1] = -g[:, 0]
pins = np.array([0, n_side - 1])
free = np.setdiff1d(np.arange(N), pins)
dist = np.linalg.norm(pos[:, None, :] - pos[pins][None], axis=2).astype(np.float32) * 1.01

x = wp.array(pos, dtype=wp.vec3, device=dev); xi = wp.clone(x); dq = wp.zeros(N, dtype=wp.vec3, device=dev)
particle = wp.array(free.astype(np.int32), dtype=int, device=dev)
pin_rows = wp.array(np.tile(pins, (len(free), 1)).astype(np.int32), dtype=int, device=dev)
len_rows = wp.array(dist[free], dtype=float, device=dev)
pin_all = np.tile(pins, (N, 1)).astype(np.int32); pin_all[pins] = -1
len_all = dist.copy(); len_all[pins] = -1.0
pin_all = wp.array(pin_all, dtype=int, device=dev); len_all = wp.array(len_all, dtype=float, device=dev)
slots = np.tile(np.arange(2), (N, 1)).astype(np.uint16); slots[pins] = 0xFFFF
slots = wp.array(slots, dtype=wp.uint16, device=dev); pin_particle = wp.array(pins.astype(np.int32), dtype=int, device=dev)
inv_mass = np.ones(N, np.float32); inv_mass[pins] = 0; inv_mass = wp.array(inv_mass, dtype=float, device=dev)
vs, ao = 0.9999, wp.vec3(0.0, -6.6e-7, 0.0)
k_table = instance(verlet_step_tethered, wp.vec3)
k_plain = instance(verlet_step, wp.vec3)
variants = {
    "table (particle, pin int32, length)": (k_table, len(free), [x, xi, dq, vs, ao, particle, pin_rows, len_rows]),
    "all rows (pin int32, length; pins length<0)": (step_all_rows, N, [x, xi, dq, vs, ao, pin_all, len_all]),
    "all rows, uint16 pin slots": (step_slots, N, [x, xi, dq, vs, ao, slots, pin_particle, len_all]),
    "untethered step (inv_mass)": (k_plain, N, [x, xi, dq, inv_mass, vs, ao]),
}
R = 400
for rep in range(3):
    for name, (k, dim, args) in variants.items():
        for _ in range(5):
            wp.launch(k, dim, inputs=args, device=dev)
        wp.synchronize_device(dev)
        with wp.ScopedCapture(device=dev) as cap:
            for _ in range(R):
                wp.launch(k, dim, inputs=args, device=dev)
        wp.capture_launch(cap.graph); wp.synchronize_device(dev)
        t = time.perf_counter()
        wp.capture_launch(cap.graph); wp.synchronize_device(dev)
        us = (time.perf_counter() - t) / R * 1e6
        print(f"{n_side}^2 rep {rep}  {name:48s} {us:7.2f} us", flush=True)
