/* Scalar libm calls as the compiled model kernel makes them for mid-zone pairs
 * (emulator/receiver/model_kernel.c: cbrt(sqrt(e)) and atan(g1 / g0)), for the benchmark's
 * account of that kernel's cost (tests/perf/bench_model.py). Same flags as the kernel. */
#include <math.h>
#include <stdint.h>

void libm_pass(int64_t n, const double *x, const double *y, double *out, int which) {
    if (which == 0)
        for (int64_t i = 0; i < n; i++) out[i] = sqrt(x[i]);
    else if (which == 1)
        for (int64_t i = 0; i < n; i++) out[i] = cbrt(x[i]);
    else
        for (int64_t i = 0; i < n; i++) out[i] = atan(y[i] / x[i]);
}
