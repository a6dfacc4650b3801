/* The receiver model of BRIEF section 3 as a plain C loop, for the benchmark only.
 * Same formulation as emulator/model.py (unit direction u, safe norms, d = r c / cbrt|u|),
 * ideal receiver, N receiver poses x M static transmitters, rotation matrices given. */
#include <math.h>
#include <stdint.h>

/* Same norm as emulator.model.norm3: sqrt of squares, hypot only when they could
 * under- or overflow. */
static double norm3(double x, double y, double z) {
    double s = x * x + y * y + z * z;
    return (s > 1e-290 && s < 1e290) ? sqrt(s) : hypot(hypot(x, y), z);
}

static double norm2(double x, double y) {
    double s = x * x + y * y;
    return (s > 1e-290 && s < 1e290) ? sqrt(s) : hypot(x, y);
}

static double round_half_away(double x) {
    double t = trunc(x);
    return fabs(x - t) >= 0.5 ? t + copysign(1.0, x) : t;
}

void model_loop(int64_t n, int64_t m,
                const double *rx_p, const double *rx_r,   /* (n,3), (n,3,3) */
                const double *tx_p, const double *tx_r,   /* (m,3), (m,3,3) */
                double dist_scale, double r_inner, double r_outer,
                int64_t *d_out, int64_t *delta_out) {
    for (int64_t i = 0; i < n; i++) {
        const double *R = rx_r + 9 * i;
        for (int64_t j = 0; j < m; j++) {
            const double *T = tx_r + 9 * j;
            double dx = rx_p[3 * i] - tx_p[3 * j];
            double dy = rx_p[3 * i + 1] - tx_p[3 * j + 1];
            double dz = rx_p[3 * i + 2] - tx_p[3 * j + 2];
            double r = norm3(dx, dy, dz);
            int64_t k = i * m + j;
            if (r == 0.0) { d_out[k] = 0; delta_out[k] = 0; continue; }
            double nx = dx / r, ny = dy / r, nz = dz / r;
            /* u_w = 3 x n - m, m = R_t e_x, x = m.n (see emulator/model.py) */
            double x3 = 3.0 * (T[0] * nx + T[3] * ny + T[6] * nz);
            double w0 = x3 * nx - T[0], w1 = x3 * ny - T[3], w2 = x3 * nz - T[6];
            double g0 = R[0] * w0 + R[3] * w1 + R[6] * w2;
            double g1 = R[1] * w0 + R[4] * w1 + R[7] * w2;
            double g2 = R[2] * w0 + R[5] * w1 + R[8] * w2;
            double ds = r * dist_scale;
            double d3 = ds / cbrt(norm3(g0, g1, g2));
            if (d3 <= r_inner) { d_out[k] = (int64_t)round_half_away(100 * d3); delta_out[k] = 0; continue; }
            double gxy = norm2(g0, g1);
            double dxy = gxy > 0 ? ds / cbrt(gxy) : INFINITY;
            if (dxy <= r_outer) {
                double a = g0 == 0 ? copysign(90.0, g1) : atan(g1 / g0) * (180.0 / M_PI);
                double dl = round_half_away(a);
                d_out[k] = (int64_t)round_half_away(100 * dxy);
                delta_out[k] = (int64_t)(dl > 89 ? 89 : dl < -89 ? -89 : dl);
            } else { d_out[k] = -1; delta_out[k] = -1; }
        }
    }
}
