/* Single-threaded C reference for warp_verlet's CPU step: summed-form Verlet plus coloured Gauss-Seidel
 * stick relaxation, the same arithmetic as kernels/integrate.py (verlet_step) and kernels/relax.py
 * (relax_colour), in float32.
 *
 * The sticks are given in the simulator's device order (sorted by colour), so one sequential pass over
 * them is one Gauss-Seidel sweep of the coloured solver: within a colour no two sticks share a particle,
 * so their order does not matter, and the colours come one after the other as the launches do.
 *
 * Built by bench/cpu_reference.py with `cc -O3 -march=native -shared -fPIC` and called through ctypes.
 * Positions are (n, 3) float32 arrays, sticks (m, 2) int32.
 */
#include <math.h>
#include <stdint.h>

#define MIN_LENGTH 1.0e-9f

/* x_prev = x0 + a dt^2 / 2 (start from rest): stored as delta = x0 - x_prev and x_inertial = x0. */
void verlet_start(int n, const float *x, const float *inv_mass, const float *accel, float dt,
                  float *x_inertial, float *delta)
{
    float half = 0.5f * dt * dt;
    for (int i = 0; i < n; ++i) {
        for (int k = 0; k < 3; ++k) {
            x_inertial[3 * i + k] = x[3 * i + k];
            delta[3 * i + k] = inv_mass[i] == 0.0f ? 0.0f : 0.0f * dt - accel[k] * half;
        }
    }
}

static void verlet_step(int n, float *x, float *x_inertial, float *delta, const float *inv_mass,
                        float velocity_scale, const float *accel_offset)
{
    for (int i = 0; i < n; ++i) {
        if (inv_mass[i] == 0.0f)
            continue; /* pins never move */
        for (int k = 0; k < 3; ++k) {
            float xi = x[3 * i + k];
            float move = delta[3 * i + k] + (xi - x_inertial[3 * i + k]);
            float step = move * velocity_scale + accel_offset[k];
            xi = xi + step;
            x[3 * i + k] = xi;
            x_inertial[3 * i + k] = xi;
            delta[3 * i + k] = step;
        }
    }
}

/* One Gauss-Seidel sweep over all sticks, in the given order. weight is the stick's weight (kernels/relax.py:
 * 1 while it holds, 0 once torn); the sticks are rigid. */
void relax_sweep(float *x, const float *inv_mass, int m, const int32_t *ends, const float *rest,
                 const float *weight)
{
    for (int s = 0; s < m; ++s) {
        int i = ends[2 * s], j = ends[2 * s + 1];
        float wi = inv_mass[i], wj = inv_mass[j];
        float *xi = x + 3 * i, *xj = x + 3 * j;
        float dx = xj[0] - xi[0], dy = xj[1] - xi[1], dz = xj[2] - xi[2];
        float length = sqrtf(dx * dx + dy * dy + dz * dz);
        float w = wi + wj;
        if (w == 0.0f || length < MIN_LENGTH)
            continue;
        float f = weight[s] * (length - rest[s]) / (length * w);
        float cx = dx * f, cy = dy * f, cz = dz * f;
        xi[0] += cx * wi; xi[1] += cy * wi; xi[2] += cz * wi;
        xj[0] -= cx * wj; xj[1] -= cy * wj; xj[2] -= cz * wj;
    }
}

/* `substeps` fixed steps: Verlet, then `iterations` sweeps. The caller runs verlet_start once first. */
void step_frame(int n, float *x, float *x_inertial, float *delta, const float *inv_mass, int m,
                const int32_t *ends, const float *rest, const float *weight, int substeps, int iterations,
                float velocity_scale, const float *accel_offset)
{
    for (int step = 0; step < substeps; ++step) {
        verlet_step(n, x, x_inertial, delta, inv_mass, velocity_scale, accel_offset);
        for (int it = 0; it < iterations; ++it)
            relax_sweep(x, inv_mass, m, ends, rest, weight);
    }
}
