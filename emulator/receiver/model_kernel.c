/* The batch model's fast path (emulator/receiver/model.py, "Fast path") as one fused C loop.
 *
 * Optional extension module emulator.receiver.model_kernel, built by setup.py when a C
 * compiler is present (-O3 -ffp-contract=off, no -ffast-math). Without it the numpy fast
 * path runs; ARVA_MODEL_KERNEL=numpy|compiled chooses (see model.py, KERNEL).
 *
 * Same formulation as model._fast_block, in blocks of BLK poses that stay in L1: per
 * transmitter a branch-free loop over the block's poses (vectorised by the compiler; the
 * same IEEE operations as scalar code), then a loop that decides zones without a branch
 * on the zone; mid pairs wait in a small buffer for their roots (flush). Units:
 * metres; quaternions [w, x, y, z] rotate body into world, need not be normalised. With
 * d = p_r - p_t, s = |d|^2, a = R_r^T d, b = lam R_r^T m and md3 = 3 lam m.d:
 *
 *     G = md3 a - s b,   q = G_x^2 + G_y^2,   e = s^5 / q = (200 dxy)^6
 *
 * outer when e > e_hi (no root at all); mid pairs take sqrt, cbrt and atan:
 * d = floor((cbrt(sqrt(e)) + 1) / 2), delta = clip(floor(deg(atan(G_y / G_x)) + 90.5) - 90, +-89).
 * Inner candidates (s <= s_inner) are decided from 200 d3 = (s^5 / (q + G_z^2))^(1/6).
 *
 * A pair is left UNDECIDED (zone -1; d and delta then unspecified) under the same rules
 * and margins as the numpy fast path: pose |q|^2 outside [q2_lo, q2_hi]; s outside
 * [s_lo, s_hi]; |p_r|^2 + |p_t|^2 > cancel * s; within the relative margin of the zone
 * boundary, of a rounding boundary of d (d_tol) or of delta (deg_tol), or of atan's fold
 * at +-90 (fold_tol); an inner candidate within the margin of r_inner or of a rounding
 * boundary. Python sends the undecided pairs to the general path, so every integer is the
 * general path's. Range tests are written so that a NaN makes the pair undecided; for s in
 * range e is never NaN (s^5 > 0; q = 0 gives inf, outer).
 *
 * Plain C99 and CPython's buffer protocol (no numpy headers); the loop runs without the GIL.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>

#define ZONE_INNER 0
#define ZONE_MID 1
#define ZONE_OUTER 2
#define ZONE_UNDECIDED (-1)
#define TX_COLS 10 /* per transmitter: p (3), lam m (3), 3 lam m (3), |p|^2 */

typedef struct {
    double e_lo, e_hi, d_tol, deg_tol, fold_tol, s_lo, s_hi, cancel, q2_lo, q2_hi;
    double s_inner, v_inner, edge;
} consts_t;

static const double RAD2DEG = 57.29577951308232; /* 180 / pi, as math.pi gives it */

static int near_integer(double x, double fl, double tol) {
    double f = x - fl;
    return (f < tol) | (f > 1.0 - tol);
}

/* A mid-zone pair (e <= e_hi): d and delta from e = (200 dxy)^6 and G_x, G_y. Returns 1
 * (undecided) within the margins of a boundary, else 0 with *d and *delta set. */
static int mid_pair(double e, double g0, double g1, const consts_t *c, int64_t *d, int64_t *delta) {
    int und = e > c->e_lo;
    double v = (cbrt(sqrt(e)) + 1.0) * 0.5; /* 100 dxy + 1/2 */
    double ang = atan(g1 / g0) * RAD2DEG + 90.5;
    double fl = floor(v);
    und |= near_integer(v, fl, c->d_tol);
    double kf = floor(ang);
    und |= near_integer(ang, kf, c->deg_tol);
    und |= !(fabs(ang - 90.5) <= 90.0 - c->fold_tol);
    *d = (int64_t)fl;  /* fl < 2^31 for e <= e_hi */
    int64_t kk = (int64_t)kf - 90; /* kf in [0, 180] */
    *delta = kk > 89 ? 89 : kk < -89 ? -89 : kk;
    return und;
}

/* Mid pairs wait here and are finished in one loop (sqrt, cbrt, atan), away from the pair
 * loop, which thus has no branch on the zone. */
#define PENDING 256
typedef struct {
    Py_ssize_t k[PENDING];
    double e[PENDING], g0[PENDING], g1[PENDING];
    int count;
} pending_t;

static Py_ssize_t flush(pending_t *p, const consts_t *c, int64_t *d_out, int64_t *delta_out, int8_t *zone_out) {
    Py_ssize_t undecided = 0;
    for (int i = 0; i < p->count; i++) {
        Py_ssize_t k = p->k[i];
        if (mid_pair(p->e[i], p->g0[i], p->g1[i], c, d_out + k, delta_out + k)) {
            zone_out[k] = ZONE_UNDECIDED;
            undecided++;
        }
    }
    p->count = 0;
    return undecided;
}

/* Rotation of q / |q| (all 9 entries, R[3 * row + col]) and |q|^2, the operations of
 * emulator.frames.rotation.rotation_unnormalized_components. */
static double pose_rotation(const double *qq, double *R) {
    double w = qq[0], x = qq[1], y = qq[2], z = qq[3];
    double n2 = (w * w + y * y) + (x * x + z * z);
    double k = 2.0 / n2;
    double kx = k * x, ky = k * y, kz = k * z;
    double xx = kx * x, yy = ky * y, zz = kz * z;
    double xy = kx * y, yz = ky * z, xz = kx * z;
    double wx = kx * w, wy = ky * w, wz = kz * w;
    R[0] = 1.0 - (yy + zz); R[3] = xy + wz; R[6] = xz - wy;
    R[1] = xy - wz; R[4] = 1.0 - (xx + zz); R[7] = yz + wx;
    R[2] = xz + wy; R[5] = yz - wx; R[8] = 1.0 - (xx + yy);
    return n2;
}

/* Poses per block: 16 measured best of 4..512 (13.5 vs 15.0 ns/pair at 128, in-process A/B,
 * 1e6 poses x 4 tx, CPU time, 2026-12-02, load 6): the block's outputs stay in L1 too. */
#define BLK 16

/* A pair the pair loop flags as rare: outside the fast path's ranges (undecided), or an
 * inner candidate (s <= s_inner), decided here from the loop's s, e, G, 3 m.d and q plus
 * the z antenna's column R[2], R[5], R[8]. Returns 1 if undecided. */
static int rare_pair(const double *pr, const double *R, const double *t, double rx2, double s, double e,
                     double g0, double g1, double md3, double q, const consts_t *c,
                     int64_t *d_out, int64_t *delta_out, int8_t *zone_out) {
    if (!(s > c->s_lo && s < c->s_hi && rx2 + t[9] <= c->cancel * s)) {
        *zone_out = ZONE_UNDECIDED;
        return 1;
    }
    int zone = ZONE_OUTER, und = 0;
    int64_t d = -1, delta = -1;
    if (e <= c->e_hi) {
        zone = ZONE_MID;
        und = mid_pair(e, g0, g1, c, &d, &delta);
    }
    if (!und) { /* s <= s_inner: may be inner, 200 d3 = (s^5 / (q + G_z^2))^(1/6) */
        double dx = pr[0] - t[0], dy = pr[1] - t[1], dz = pr[2] - t[2];
        double a2 = (R[2] * dx + R[5] * dy) + R[8] * dz;
        double b2 = (R[2] * t[3] + R[5] * t[4]) + R[8] * t[5];
        double gz = md3 * a2 - s * b2;
        double s2 = s * s;
        double v3 = cbrt(sqrt(s2 * s2 * s / (q + gz * gz)));
        double wv = (v3 + 1.0) * 0.5;
        double fl = floor(wv);
        if (!(fabs(v3 - c->v_inner) > c->edge * c->v_inner) || near_integer(wv, fl, c->d_tol)) {
            und = 1;
        } else if (v3 <= c->v_inner) {
            zone = ZONE_INNER;
            d = (int64_t)fl;
            delta = 0;
        }
    }
    *zone_out = (int8_t)(und ? ZONE_UNDECIDED : zone);
    *d_out = d;
    *delta_out = delta;
    return und;
}

static Py_ssize_t kernel(Py_ssize_t n, Py_ssize_t m, const double *restrict rx_p,
                         const double *restrict rx_q, const double *restrict tx, const consts_t *c,
                         int64_t *restrict d_out, int64_t *restrict delta_out, int8_t *restrict zone_out) {
    const double q2_lo = c->q2_lo, q2_hi = c->q2_hi, s_lo = c->s_lo, s_hi = c->s_hi;
    const double cancel = c->cancel, s_inner = c->s_inner, e_hi = c->e_hi;
    double R0[BLK], R3[BLK], R6[BLK], R1[BLK], R4[BLK], R7[BLK], PX[BLK], PY[BLK], PZ[BLK], RX2[BLK];
    double E[BLK], S[BLK], G0[BLK], G1[BLK], MD3[BLK], Q[BLK];
    int ok[BLK];
    Py_ssize_t undecided = 0;
    pending_t pend;
    pend.count = 0;
    for (Py_ssize_t i0 = 0; i0 < n; i0 += BLK) {
        int nb = (int)(n - i0 < BLK ? n - i0 : BLK);
        for (int ii = 0; ii < nb; ii++) {
            double R[9];
            double n2 = pose_rotation(rx_q + 4 * (i0 + ii), R);
            ok[ii] = n2 > q2_lo && n2 < q2_hi;
            R0[ii] = R[0]; R3[ii] = R[3]; R6[ii] = R[6];
            R1[ii] = R[1]; R4[ii] = R[4]; R7[ii] = R[7];
            const double *pr = rx_p + 3 * (i0 + ii);
            PX[ii] = pr[0]; PY[ii] = pr[1]; PZ[ii] = pr[2];
            RX2[ii] = (pr[0] * pr[0] + pr[1] * pr[1]) + pr[2] * pr[2];
        }
        for (Py_ssize_t j = 0; j < m; j++) {
            const double *t = tx + TX_COLS * j;
            const double t0 = t[0], t1 = t[1], t2 = t[2], t3 = t[3], t4 = t[4], t5 = t[5];
            const double t6 = t[6], t7 = t[7], t8 = t[8], t9 = t[9];
            for (int ii = 0; ii < nb; ii++) { /* no branches: vectorised by the compiler */
                double dx = PX[ii] - t0, dy = PY[ii] - t1, dz = PZ[ii] - t2;
                double s = (dx * dx + dy * dy) + dz * dz;
                double a0 = (R0[ii] * dx + R3[ii] * dy) + R6[ii] * dz;
                double a1 = (R1[ii] * dx + R4[ii] * dy) + R7[ii] * dz;
                double b0 = (R0[ii] * t3 + R3[ii] * t4) + R6[ii] * t5;
                double b1 = (R1[ii] * t3 + R4[ii] * t4) + R7[ii] * t5;
                double md3 = (t6 * dx + t7 * dy) + t8 * dz;
                double g0 = md3 * a0 - s * b0, g1 = md3 * a1 - s * b1;
                double q = g0 * g0 + g1 * g1;
                double s2 = s * s;
                S[ii] = s;
                E[ii] = s2 * s2 * s / q; /* (200 dxy)^6; q = 0: inf, outer */
                MD3[ii] = md3;
                Q[ii] = q;
                G0[ii] = g0;
                G1[ii] = g1;
            }
            for (int ii = 0; ii < nb; ii++) {
                Py_ssize_t k = (i0 + ii) * m + j;
                double s = S[ii], e = E[ii];
                if (!(ok[ii] && s > s_lo && s < s_hi && RX2[ii] + t9 <= cancel * s) || s <= s_inner) {
                    if (!ok[ii]) {
                        zone_out[k] = ZONE_UNDECIDED;
                        undecided++;
                    } else {
                        double R[9];
                        pose_rotation(rx_q + 4 * (i0 + ii), R);
                        undecided += rare_pair(rx_p + 3 * (i0 + ii), R, t, RX2[ii], s, e, G0[ii], G1[ii], MD3[ii],
                                               Q[ii], c, d_out + k, delta_out + k, zone_out + k);
                    }
                    continue;
                }
                int mid = e <= e_hi;
                zone_out[k] = (int8_t)(ZONE_OUTER - mid);
                d_out[k] = -1;
                delta_out[k] = -1;
                int at = pend.count;
                pend.k[at] = k;
                pend.e[at] = e;
                pend.g0[at] = G0[ii];
                pend.g1[at] = G1[ii];
                pend.count += mid;
                if (pend.count == PENDING)
                    undecided += flush(&pend, c, d_out, delta_out, zone_out);
            }
        }
    }
    undecided += flush(&pend, c, d_out, delta_out, zone_out);
    return undecided;
}

static int check_len(Py_buffer *b, Py_ssize_t count, Py_ssize_t itemsize, const char *name) {
    if (b->len != count * itemsize) {
        PyErr_Format(PyExc_ValueError, "model_kernel.fast_pairs: %s has %zd bytes, expected %zd",
                     name, b->len, count * itemsize);
        return 0;
    }
    return 1;
}

PyDoc_STRVAR(fast_pairs_doc,
"fast_pairs(rx_p, rx_q, tx, consts, d, delta, zone) -> undecided count\n\n"
"rx_p (n, 3) and rx_q (n, 4) float64, tx (m, 10) float64 [p, lam m, 3 lam m, |p|^2],\n"
"consts a tuple of 13 floats (e_lo, e_hi, d_tol, deg_tol, fold_tol, s_lo, s_hi, cancel,\n"
"q2_lo, q2_hi, s_inner, v_inner, edge); outputs d, delta (n, m) int64 and zone (n, m) int8,\n"
"all C-contiguous. Pairs left to the general path get zone -1.");

static PyObject *fast_pairs(PyObject *self, PyObject *args) {
    Py_buffer bp = {0}, bq = {0}, bt = {0}, bd = {0}, bl = {0}, bz = {0};
    consts_t c;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*(ddddddddddddd)w*w*w*:fast_pairs", &bp, &bq, &bt,
                          &c.e_lo, &c.e_hi, &c.d_tol, &c.deg_tol, &c.fold_tol, &c.s_lo, &c.s_hi,
                          &c.cancel, &c.q2_lo, &c.q2_hi, &c.s_inner, &c.v_inner, &c.edge,
                          &bd, &bl, &bz))
        return NULL;
    Py_ssize_t n = bp.len / (Py_ssize_t)(3 * sizeof(double));
    Py_ssize_t m = bt.len / (Py_ssize_t)(TX_COLS * sizeof(double));
    if (check_len(&bp, 3 * n, sizeof(double), "rx_p") && check_len(&bq, 4 * n, sizeof(double), "rx_q")
        && check_len(&bt, TX_COLS * m, sizeof(double), "tx") && check_len(&bd, n * m, sizeof(int64_t), "d")
        && check_len(&bl, n * m, sizeof(int64_t), "delta") && check_len(&bz, n * m, 1, "zone")) {
        Py_ssize_t und;
        Py_BEGIN_ALLOW_THREADS
        und = kernel(n, m, (const double *)bp.buf, (const double *)bq.buf, (const double *)bt.buf, &c,
                     (int64_t *)bd.buf, (int64_t *)bl.buf, (int8_t *)bz.buf);
        Py_END_ALLOW_THREADS
        result = PyLong_FromSsize_t(und);
    }
    PyBuffer_Release(&bp);
    PyBuffer_Release(&bq);
    PyBuffer_Release(&bt);
    PyBuffer_Release(&bd);
    PyBuffer_Release(&bl);
    PyBuffer_Release(&bz);
    return result;
}

static PyMethodDef methods[] = {
    {"fast_pairs", fast_pairs, METH_VARARGS, fast_pairs_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "model_kernel",
    "The batch model's fast path as one compiled loop (see emulator/receiver/model_kernel.c).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit_model_kernel(void) { return PyModule_Create(&module); }
