/*
 * jacobian_timing.c - timing loops for bench/bench_jacobian.py: `reps` calls of one kernel
 * function (fp_plant.c, linked into the same library) at one state, timed in C with a monotonic
 * clock, so that no Python call overhead enters the comparison. Each returns the seconds per
 * call; a result of every call is summed into *sink (the calls cannot be elided: fp_plant.c is
 * another translation unit).
 */
#define _POSIX_C_SOURCE 199309L
#include <time.h>

#include "fp_plant.h"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

FP_API double fpb_time_rhs(const fp_plant *p, const double *x, double u, long reps, double *out,
                           double *sink)
{
    double t0 = now(), acc = 0.0;
    long i;
    for (i = 0; i < reps; i++) {
        fp_rhs(p, x, u, out);
        acc += out[p->nx - 1];
    }
    *sink += acc;
    return (now() - t0) / (double)reps;
}

FP_API double fpb_time_jacobian(const fp_plant *p, const double *x, double u, long reps,
                                double *J, double *b, double *work, double *sink)
{
    double t0 = now(), acc = 0.0;
    long i;
    for (i = 0; i < reps; i++) {
        fp_jacobian(p, x, u, J, b, work);
        acc += J[p->nx * p->nx - 1];
    }
    *sink += acc;
    return (now() - t0) / (double)reps;
}

FP_API double fpb_time_jvp(const fp_plant *p, const double *x, double u, const double *v,
                           long reps, double *out, double *work, double *sink)
{
    double t0 = now(), acc = 0.0;
    long i;
    for (i = 0; i < reps; i++) {
        fp_jvp(p, x, u, v, 1.0, out, work);
        acc += out[p->nx - 1];
    }
    *sink += acc;
    return (now() - t0) / (double)reps;
}

FP_API double fpb_time_output_derivatives(const fp_plant *p, const double *x, double u,
                                          long reps, double *d1, double *d2, double *work,
                                          double *sink)
{
    double t0 = now(), acc = 0.0;
    long i;
    for (i = 0; i < reps; i++) {
        fp_output_derivatives(p, x, u, 1.0, d1, d2, work);
        acc += d2[0];
    }
    *sink += acc;
    return (now() - t0) / (double)reps;
}
