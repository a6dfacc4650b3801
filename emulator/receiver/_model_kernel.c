/* The batch model's fast path (emulator/receiver/model.py, "Fast path") as one fused C loop.
 *
 * Optional extension module emulator.receiver._model_kernel, built by setup.py when a C
 * compiler is present (-O3 -ffp-contract=off, no -ffast-math). Without it the numpy fast
 * path runs; ARVA_MODEL_KERNEL=numpy|compiled chooses (see model.py, KERNEL).
 *
 * Same formulation as model._fast_block, pair by pair, nothing stored in between. Units:
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
 * general path's. Every test is written so that a NaN makes the pair undecided.
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

/* Mid pairs wait here and are finished in one loop, away from the pair loop's
 * unpredictable zone branch (about 1 ns/pair less than finishing them inline, 2026-12-02). */
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

/* Poses [0, n) against m transmitters; outputs (n, m) row-major. Returns the number of
 * undecided pairs. */
static Py_ssize_t kernel(Py_ssize_t n, Py_ssize_t m, const double *restrict rx_p,
                         const double *restrict rx_q, const double *restrict tx, const consts_t *c,
                         int64_t *restrict d_out, int64_t *restrict delta_out, int8_t *restrict zone_out) {
    /* Locals: the int8 zone stores could alias *c for the compiler, forcing reloads. */
    const double q2_lo = c->q2_lo, q2_hi = c->q2_hi, s_lo = c->s_lo, s_hi = c->s_hi;
    const double cancel = c->cancel, s_inner = c->s_inner, e_hi = c->e_hi;
    Py_ssize_t undecided = 0;
    pending_t pend;
    pend.count = 0;
    for (Py_ssize_t i = 0; i < n; i++) {
        const double *pr = rx_p + 3 * i, *qq = rx_q + 4 * i;
        int64_t *dd = d_out + i * m, *dl = delta_out + i * m;
        int8_t *zz = zone_out + i * m;
        /* Rotation columns of q / |q| without normalising q (the operations of
         * emulator.frames.rotation.rotation_unnormalized_components). */
        double w = qq[0], x = qq[1], y = qq[2], z = qq[3];
        double n2 = (w * w + y * y) + (x * x + z * z);
        if (!(n2 > q2_lo && n2 < q2_hi)) {
            for (Py_ssize_t j = 0; j < m; j++) zz[j] = ZONE_UNDECIDED;
            undecided += m;
            continue;
        }
        double k = 2.0 / n2;
        double kx = k * x, ky = k * y, kz = k * z;
        double xx = kx * x, yy = ky * y, zzq = kz * z;
        double xy = kx * y, yz = ky * z, xz = kx * z;
        double wx = kx * w, wy = ky * w, wz = kz * w;
        double r00 = 1.0 - (yy + zzq), r10 = xy + wz, r20 = xz - wy; /* column 0: x antenna */
        double r01 = xy - wz, r11 = 1.0 - (xx + zzq), r21 = yz + wx; /* column 1: y antenna */
        double px = pr[0], py = pr[1], pz = pr[2];
        double rx2 = (px * px + py * py) + pz * pz;
        for (Py_ssize_t j = 0; j < m; j++) {
            const double *t = tx + TX_COLS * j;
            double dx = px - t[0], dy = py - t[1], dz = pz - t[2];
            double s = (dx * dx + dy * dy) + dz * dz;
            if (!(s > s_lo && s < s_hi && rx2 + t[9] <= cancel * s)) {
                zz[j] = ZONE_UNDECIDED;
                undecided++;
                continue;
            }
            double a0 = (r00 * dx + r10 * dy) + r20 * dz;
            double a1 = (r01 * dx + r11 * dy) + r21 * dz;
            double b0 = (r00 * t[3] + r10 * t[4]) + r20 * t[5];
            double b1 = (r01 * t[3] + r11 * t[4]) + r21 * t[5];
            double md3 = (t[6] * dx + t[7] * dy) + t[8] * dz;
            double g0 = md3 * a0 - s * b0, g1 = md3 * a1 - s * b1;
            double q = g0 * g0 + g1 * g1;
            double s2 = s * s;
            double s5 = s2 * s2 * s;
            double e = s5 / q; /* (200 dxy)^6; q = 0: inf, outer */
            if (s <= s_inner) { /* rare: may be inner (d3 from the z antenna too) */
                int zone = ZONE_OUTER, und = 0;
                int64_t d = -1, delta = -1;
                if (e <= e_hi) {
                    zone = ZONE_MID;
                    und = mid_pair(e, g0, g1, c, &d, &delta);
                }
                if (!und) {
                    double r02 = xz + wy, r12 = yz - wx, r22 = 1.0 - (xx + yy);
                    double a2 = (r02 * dx + r12 * dy) + r22 * dz;
                    double b2 = (r02 * t[3] + r12 * t[4]) + r22 * t[5];
                    double gz = md3 * a2 - s * b2;
                    double v3 = cbrt(sqrt(s5 / (q + gz * gz))); /* 200 d3 */
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
                zz[j] = (int8_t)(und ? ZONE_UNDECIDED : zone);
                undecided += und;
                dd[j] = d;
                dl[j] = delta;
            } else if (e <= e_hi) {
                zz[j] = ZONE_MID;
                int at = pend.count++;
                pend.k[at] = i * m + j;
                pend.e[at] = e;
                pend.g0[at] = g0;
                pend.g1[at] = g1;
                if (pend.count == PENDING)
                    undecided += flush(&pend, c, d_out, delta_out, zone_out);
            } else {
                zz[j] = ZONE_OUTER;
                dd[j] = -1;
                dl[j] = -1;
            }
        }
    }
    undecided += flush(&pend, c, d_out, delta_out, zone_out);
    return undecided;
}

static int check_len(Py_buffer *b, Py_ssize_t count, Py_ssize_t itemsize, const char *name) {
    if (b->len != count * itemsize) {
        PyErr_Format(PyExc_ValueError, "_model_kernel.fast_pairs: %s has %zd bytes, expected %zd",
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
    PyModuleDef_HEAD_INIT, "_model_kernel",
    "The batch model's fast path as one compiled loop (see emulator/receiver/_model_kernel.c).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__model_kernel(void) { return PyModule_Create(&module); }
