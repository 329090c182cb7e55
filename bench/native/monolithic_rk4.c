/*
 * monolithic_rk4.c - the physical limit of bench/bench_native.py (T5): the closed loop of the
 * filtered scene as one ODE (plant state and filter state), integrated by classical RK4 at a fixed
 * step, compiled from the same C kernels (fp_plant.c for the plant's right-hand side and tip
 * angle). No co-simulation, no FMI, no Python in the timed loop.
 *
 * stdin: n linear preload I0 I1 I2 g, then n values each of I3 I5 K D tip_slope tip_defl, n*n of
 *        Kg, then kp kd kx cutoff damping force_limit, x0 phi0 xdot0 phidot0, h t_end dt_out
 * stdout: the seconds of the integration, then phi_o at every output point.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "fp_plant.h"

#define NMAX 16
#define NX (2 * (NMAX + 2) + 2)

static fp_plant P;
static double kp, kd, kx, wc, zf, lim;

static void rhs(const double *z, double *dz)
{
    int nx = P.nx;
    double tip[2], e, F;
    fp_tip(&P, z, tip);
    F = -z[nx];
    if (F < -lim) F = -lim;
    if (F > lim) F = lim;
    fp_rhs(&P, z, F, dz);
    e = kx * z[0] + kp * tip[0] + kd * tip[1];
    dz[nx] = z[nx + 1];                                    /* filter: x1' = x2 */
    dz[nx + 1] = -(wc * wc) * z[nx] - 2.0 * zf * wc * z[nx + 1] + (wc * wc) * e;
}

static int rd(double *v)
{
    return scanf("%lf", v) == 1;
}

int main(void)
{
    static double I3[NMAX], I5[NMAX], K[NMAX], D[NMAX], ts[NMAX], td[NMAX], Kg[NMAX * NMAX];
    double z[NX], k1[NX], k2[NX], k3[NX], k4[NX], w[NX], h, t_end, dt_out, tip[2];
    double *arrays[6] = {I3, I5, K, D, ts, td}, v;
    int n, lin, pre, i, j, m;
    long steps, per_out, s;
    struct timespec a, b;
    double *out;
    if (scanf("%d %d %d", &n, &lin, &pre) != 3 || n < 0 || n > NMAX) return 2;
    P.n = n;
    P.linear = lin;
    P.preload = pre;
    if (!rd(&P.I0) || !rd(&P.I1) || !rd(&P.I2) || !rd(&P.g)) return 2;
    for (j = 0; j < 6; j++)
        for (i = 0; i < n; i++)
            if (!rd(&arrays[j][i])) return 2;
    for (i = 0; i < n * n; i++)
        if (!rd(&Kg[i])) return 2;
    P.I3 = I3; P.I5 = I5; P.K = K; P.D = D; P.tip_slope = ts; P.tip_defl = td; P.Kg = Kg;
    if (fp_plant_prepare(&P) != FP_OK) return 3;
    if (!rd(&kp) || !rd(&kd) || !rd(&kx) || !rd(&wc) || !rd(&zf) || !rd(&lim)) return 2;
    m = P.nx + 2;
    for (i = 0; i < m; i++) z[i] = 0.0;
    if (!rd(&z[0]) || !rd(&z[1]) || !rd(&z[n + 2]) || !rd(&z[n + 3])) return 2;
    if (!rd(&h) || !rd(&t_end) || !rd(&dt_out)) return 2;
    steps = lround(t_end / h);
    per_out = lround(dt_out / h);
    out = (double *)malloc(sizeof(double) * (size_t)(steps / per_out + 1));
    fp_tip(&P, z, tip);
    out[0] = tip[0];
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (s = 1; s <= steps; s++) {
        rhs(z, k1);
        for (i = 0; i < m; i++) w[i] = z[i] + 0.5 * h * k1[i];
        rhs(w, k2);
        for (i = 0; i < m; i++) w[i] = z[i] + 0.5 * h * k2[i];
        rhs(w, k3);
        for (i = 0; i < m; i++) w[i] = z[i] + h * k3[i];
        rhs(w, k4);
        for (i = 0; i < m; i++) z[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        if (s % per_out == 0) {
            fp_tip(&P, z, tip);
            out[s / per_out] = tip[0];
        }
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    printf("%.9g\n", (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec));
    for (s = 0; s <= steps / per_out; s++) printf("%.17g\n", out[s]);
    (void)v;
    free(out);
    return 0;
}
