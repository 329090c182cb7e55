/*
 * fp_filter.c - the compiled kernel of the controller (see fp_filter.h for the contract).
 */
#include "fp_filter.h"

#include <math.h>
#include <stddef.h>

#ifndef FP_SOURCE_DIGEST
#define FP_SOURCE_DIGEST "unknown"
#endif

int fpf_abi(void) { return FPF_ABI; }

const char *fpf_source_digest(void) { return FP_SOURCE_DIGEST; }

int fpf_check(const fpf_filter *f)
{
    if (f == NULL || f->order < 0 || f->order > 2) return FPF_BADARG;
    if (!(isfinite(f->kp) && isfinite(f->kd) && isfinite(f->kx))) return FPF_BADARG;
    if (!(f->force_limit > 0.0)) return FPF_BADARG;     /* +inf allowed, NaN not */
    if (f->order > 0 && !(f->cutoff > 0.0 && isfinite(f->cutoff))) return FPF_BADARG;
    if (f->order == 2 && !(f->damping >= 0.0 && isfinite(f->damping))) return FPF_BADARG;
    return FPF_OK;
}

/* ------------------------------------------------------------------ matrix exponential */
/* Coefficients c_j = (2m - j)! m! / ((2m)! j! (m - j)!) of the [m/m] Pade approximant of exp. */
static const double PADE3[4] = {1.0, 0.5, 0.1, 0.008333333333333333};
static const double PADE5[6] = {1.0, 0.5, 0.1111111111111111, 0.013888888888888888,
                                0.000992063492063492, 3.306878306878307e-05};
static const double PADE7[8] = {1.0, 0.5, 0.11538461538461539, 0.016025641025641024,
                                0.001456876456876457, 8.741258741258741e-05,
                                3.2375032375032376e-06, 5.781255781255781e-08};
static const double PADE9[10] = {1.0, 0.5, 0.11764705882352941, 0.01715686274509804,
                                 0.001715686274509804, 0.00012254901960784314,
                                 6.2845651080945196e-06, 2.2444875386051856e-07,
                                 5.101108042284513e-09, 5.66789782476057e-11};
static const double PADE13[14] = {1.0, 0.5, 0.12, 0.018333333333333333, 0.0019927536231884057,
                                  0.00016304347826086958, 1.0351966873706003e-05,
                                  5.175983436853002e-07, 2.0431513566525008e-08,
                                  6.306022705717595e-10, 1.48377004840414e-11,
                                  2.529153491597966e-13, 2.8101705462199623e-15,
                                  1.5440497506703088e-17};
/* Bounds on eta (below) for degrees 3, 5, 7, 9 and on 2^-s eta for degree 13 that keep the
 * backward error below the unit roundoff (Al-Mohy & Higham 2009, Table 3.1 and Algorithm 5.1). */
static const double THETA[5] = {1.495585217958292e-2, 2.539398330063230e-1,
                                9.504178996162932e-1, 2.097847961257068e0, 4.25};
/* 1 / |c_{2m+1}|: the leading coefficient of the backward error series of the [m/m] approximant,
 * m = 3, 5, 7, 9, 13 (Higham 2005, (2.2) and (2.6)). */
static const double ELL_C[5] = {100800.0, 10059033600.0, 4487938430976000.0,
                                5914384781877411840000.0,
                                113250775606021113483283660800000000.0};

long fpf_expm_work_size(int n)
{
    if (n < 1) return 0;
    return 9L * n * n;
}

/* C = A B, all n x n; C must not overlap A or B. */
static void matmul(int n, const double *A, const double *B, double *C)
{
    int i, j, k;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            double acc = 0.0;
            for (k = 0; k < n; k++) acc += A[i * n + k] * B[k * n + j];
            C[i * n + j] = acc;
        }
}

/* Solve Q X = P in place (X overwrites P; Q is destroyed) by Gaussian elimination with partial
 * pivoting. 0 if Q is singular. */
static int solve(int n, double *Q, double *P)
{
    int i, j, k;
    for (k = 0; k < n; k++) {
        int piv = k;
        double best = fabs(Q[k * n + k]);
        for (i = k + 1; i < n; i++)
            if (fabs(Q[i * n + k]) > best) {
                best = fabs(Q[i * n + k]);
                piv = i;
            }
        if (!(best > 0.0)) return 0;
        if (piv != k)
            for (j = 0; j < n; j++) {
                double tq = Q[k * n + j], tp = P[k * n + j];
                Q[k * n + j] = Q[piv * n + j];
                Q[piv * n + j] = tq;
                P[k * n + j] = P[piv * n + j];
                P[piv * n + j] = tp;
            }
        for (i = k + 1; i < n; i++) {
            const double l = Q[i * n + k] / Q[k * n + k];
            if (l == 0.0) continue;
            for (j = k; j < n; j++) Q[i * n + j] -= l * Q[k * n + j];
            for (j = 0; j < n; j++) P[i * n + j] -= l * P[k * n + j];
        }
    }
    for (k = n - 1; k >= 0; k--)
        for (j = 0; j < n; j++) {
            double acc = P[k * n + j];
            for (i = k + 1; i < n; i++) acc -= Q[k * n + i] * P[i * n + j];
            P[k * n + j] = acc / Q[k * n + k];
        }
    return 1;
}

static double onenorm(int n, const double *A)
{
    double norm = 0.0;
    int i, j;
    for (j = 0; j < n; j++) {
        double col = 0.0;
        for (i = 0; i < n; i++) col += fabs(A[i * n + j]);
        if (col > norm) norm = col;
    }
    return norm;
}

/* The number of extra squarings ell_m(A) that keep the backward error of the [m/m] approximant
 * of the (scaled) A below the unit roundoff: ceil(log2(alpha / u) / (2m)) with
 * alpha = |c_{2m+1}| || |A|^(2m+1) ||_1 / ||A||_1 (Al-Mohy & Higham 2009, (5.2)); `scale` is the
 * factor 2^-s already applied to A. v: n doubles of work. */
static int ell(int n, const double *A, double scale, int m, int im, double *v, double *w)
{
    double a, normA = onenorm(n, A) * scale, value;
    int i, j, p;
    if (!(normA > 0.0)) return 0;
    for (j = 0; j < n; j++) v[j] = 1.0;
    for (p = 0; p < 2 * m + 1; p++) {           /* v^T <- v^T |scale A| */
        for (j = 0; j < n; j++) {
            double acc = 0.0;
            for (i = 0; i < n; i++) acc += v[i] * fabs(A[i * n + j]) * scale;
            w[j] = acc;
        }
        for (j = 0; j < n; j++) v[j] = w[j];
    }
    a = 0.0;
    for (j = 0; j < n; j++)
        if (v[j] > a) a = v[j];
    if (!(a > 0.0)) return 0;
    value = ceil(log2(a / (normA * ELL_C[im]) / ldexp(1.0, -53)) / (2 * m));
    return value > 0.0 ? (int)value : 0;
}

int fpf_expm(int n, const double *A, double *E, double *work)
{
    const int nn = n * n;
    double *As, *A2, *A4, *A6, *A8, *U, *V, *T, *Q;
    const double *c;
    double d4, d6, d8, d10, eta1, eta3, eta5;
    int i, m, s = 0;
    if (n < 1 || A == NULL || E == NULL || work == NULL) return FPF_BADARG;
    for (i = 0; i < nn; i++)
        if (!isfinite(A[i])) return FPF_BADARG;
    As = work;
    A2 = As + nn;
    A4 = A2 + nn;
    A6 = A4 + nn;
    A8 = A6 + nn;
    U = A8 + nn;
    V = U + nn;
    T = V + nn;
    Q = T + nn;                               /* 9 n^2 doubles */
    /* The degree and the scaling from the norms of powers of A (Al-Mohy & Higham 2009,
     * Algorithm 5.1, with exact norms: the matrices here are small), as scipy's expm does. */
    matmul(n, A, A, A2);
    matmul(n, A2, A2, A4);
    matmul(n, A4, A2, A6);
    d4 = pow(onenorm(n, A4), 0.25);
    d6 = pow(onenorm(n, A6), 1.0 / 6.0);
    eta1 = d4 > d6 ? d4 : d6;
    if (eta1 <= THETA[0] && ell(n, A, 1.0, 3, 0, U, V) == 0) {
        m = 3;
    } else if (eta1 <= THETA[1] && ell(n, A, 1.0, 5, 1, U, V) == 0) {
        m = 5;
    } else {
        matmul(n, A4, A4, A8);
        d8 = pow(onenorm(n, A8), 0.125);
        eta3 = d6 > d8 ? d6 : d8;
        if (eta3 <= THETA[2] && ell(n, A, 1.0, 7, 2, U, V) == 0) {
            m = 7;
        } else if (eta3 <= THETA[3] && ell(n, A, 1.0, 9, 3, U, V) == 0) {
            m = 9;
        } else {
            matmul(n, A4, A6, T);
            d10 = pow(onenorm(n, T), 0.1);
            eta5 = d8 > d10 ? d8 : d10;
            if (eta3 < eta5) eta5 = eta3;
            m = 13;
            if (eta5 > 0.0) {
                double sd = ceil(log2(eta5 / THETA[4]));
                if (sd > 1000.0) return FPF_NONFINITE;
                s = sd > 0.0 ? (int)sd : 0;
            }
            s += ell(n, A, ldexp(1.0, -s), 13, 4, U, V);
        }
    }
    c = m == 3 ? PADE3 : m == 5 ? PADE5 : m == 7 ? PADE7 : m == 9 ? PADE9 : PADE13;
    if (s > 0) {                              /* scale A and its powers by 2^-s (exact) */
        for (i = 0; i < nn; i++) {
            As[i] = ldexp(A[i], -s);
            A2[i] = ldexp(A2[i], -2 * s);
            A4[i] = ldexp(A4[i], -4 * s);
            A6[i] = ldexp(A6[i], -6 * s);
        }
    } else {
        for (i = 0; i < nn; i++) As[i] = A[i];
    }
    if (m == 13) {
        /* U = A [A6 (c13 A6 + c11 A4 + c9 A2) + c7 A6 + c5 A4 + c3 A2 + c1 I]
         * V =    A6 (c12 A6 + c10 A4 + c8 A2) + c6 A6 + c4 A4 + c2 A2 + c0 I */
        for (i = 0; i < nn; i++) T[i] = c[13] * A6[i] + c[11] * A4[i] + c[9] * A2[i];
        matmul(n, A6, T, Q);
        for (i = 0; i < nn; i++) Q[i] += c[7] * A6[i] + c[5] * A4[i] + c[3] * A2[i];
        for (i = 0; i < n; i++) Q[i * n + i] += c[1];
        matmul(n, As, Q, U);
        for (i = 0; i < nn; i++) T[i] = c[12] * A6[i] + c[10] * A4[i] + c[8] * A2[i];
        matmul(n, A6, T, V);
        for (i = 0; i < nn; i++) V[i] += c[6] * A6[i] + c[4] * A4[i] + c[2] * A2[i];
        for (i = 0; i < n; i++) V[i * n + i] += c[0];
    } else {
        /* U = A sum_k c_{2k+1} A^{2k},  V = sum_k c_{2k} A^{2k} (powers up to A^8 for m = 9) */
        const double *P[5];
        int k;
        P[0] = NULL;
        P[1] = A2;
        P[2] = A4;
        P[3] = A6;
        P[4] = A8;
        for (i = 0; i < nn; i++) {
            double u = 0.0, v = 0.0;
            for (k = 1; 2 * k <= m; k++) {
                v += c[2 * k] * P[k][i];
                if (2 * k + 1 <= m) u += c[2 * k + 1] * P[k][i];
            }
            T[i] = u;
            V[i] = v;
        }
        for (i = 0; i < n; i++) {
            T[i * n + i] += c[1];
            V[i * n + i] += c[0];
        }
        matmul(n, As, T, U);
    }
    for (i = 0; i < nn; i++) {               /* (V - U) R = (V + U) */
        Q[i] = V[i] - U[i];
        E[i] = V[i] + U[i];
    }
    if (!solve(n, Q, E)) return FPF_NONFINITE;
    for (; s > 0; s--) {                      /* undo the scaling: R^(2^s) */
        matmul(n, E, E, T);
        for (i = 0; i < nn; i++) E[i] = T[i];
    }
    for (i = 0; i < nn; i++)
        if (!isfinite(E[i])) return FPF_NONFINITE;
    return FPF_OK;
}

/* ------------------------------------------------------------------ the filter */
int fpf_discretize(const fpf_filter *f, double h, int poly, double *Ad, double *G)
{
    double M[FPF_MAX_AUG * FPF_MAX_AUG], E[FPF_MAX_AUG * FPF_MAX_AUG];
    double work[9 * FPF_MAX_AUG * FPF_MAX_AUG];
    const int n = f == NULL ? 0 : f->order;
    const int na = n + (poly ? 3 : 1), ng = poly ? 3 : 1;
    const double wc = f == NULL ? 0.0 : f->cutoff;
    int i, j, rc;
    if (fpf_check(f) != FPF_OK || !(h > 0.0) || !isfinite(h)) return FPF_BADARG;
    if (n == 0) return FPF_OK;
    if (Ad == NULL || G == NULL) return FPF_BADARG;
    for (i = 0; i < na * na; i++) M[i] = 0.0;
    /* [[Af h, Bf h, 0, 0], [0, 0, h, 0], [0, 0, 0, h], [0, 0, 0, 0]] as pd_lowpass.py builds it */
    if (n == 1) {
        M[0] = -wc * h;
        M[1] = wc * h;
    } else {
        M[0 * na + 1] = 1.0 * h;
        M[1 * na + 0] = -(wc * wc) * h;
        M[1 * na + 1] = (-2.0 * f->damping * wc) * h;
        M[1 * na + 2] = (wc * wc) * h;
    }
    if (poly) {
        M[n * na + n + 1] = h;
        M[(n + 1) * na + n + 2] = h;
    }
    rc = fpf_expm(na, M, E, work);
    if (rc != FPF_OK) return rc;
    for (i = 0; i < n; i++) {
        for (j = 0; j < n; j++) Ad[i * n + j] = E[i * na + j];
        for (j = 0; j < ng; j++) G[i * ng + j] = E[i * na + n + j];
    }
    return FPF_OK;
}

int fpf_sampled(const fpf_filter *f, double T, int tustin, double *Ad, double *Bd, double *Cd,
                double *Dd)
{
    const int n = f == NULL ? 0 : f->order;
    double A[4] = {0.0, 0.0, 0.0, 0.0}, B[2] = {0.0, 0.0};
    double wc, c, M[4], det, Mi[4], P[4];
    int i, j, k, rc;
    if (fpf_check(f) != FPF_OK || !(T > 0.0) || !isfinite(T)) return FPF_BADARG;
    if (Dd == NULL) return FPF_BADARG;
    if (n == 0) {
        *Dd = 1.0;
        return FPF_OK;
    }
    if (Ad == NULL || Bd == NULL || Cd == NULL) return FPF_BADARG;
    wc = f->cutoff;
    if (!tustin) {                            /* Cf = [1, 0], Df = 0 */
        double G[2];
        rc = fpf_discretize(f, T, 0, Ad, G);
        if (rc != FPF_OK) return rc;
        for (i = 0; i < n; i++) {
            Bd[i] = G[i];
            Cd[i] = i == 0 ? 1.0 : 0.0;
        }
        *Dd = 0.0;
        return FPF_OK;
    }
    if (!(wc * T < 3.141592653589793)) return FPF_BADARG;
    c = wc / tan(0.5 * wc * T);
    if (!(c > 0.0) || !isfinite(c)) return FPF_NONFINITE;
    if (n == 1) {                             /* the controllable canonical form (fp_filter.h) */
        A[0] = -wc;
        B[0] = wc;
    } else {
        A[1] = 1.0;
        A[2] = -(wc * wc);
        A[3] = -2.0 * f->damping * wc;
        B[1] = wc * wc;
    }
    /* M = I - A / c and its inverse (n <= 2, by the adjugate) */
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) M[i * n + j] = (i == j ? 1.0 : 0.0) - A[i * 2 + j] / c;
    if (n == 1) {
        if (M[0] == 0.0) return FPF_NONFINITE;
        Mi[0] = 1.0 / M[0];
    } else {
        det = M[0] * M[3] - M[1] * M[2];
        if (det == 0.0 || !isfinite(det)) return FPF_NONFINITE;
        Mi[0] = M[3] / det;
        Mi[1] = -M[1] / det;
        Mi[2] = -M[2] / det;
        Mi[3] = M[0] / det;
    }
    for (i = 0; i < n; i++)                   /* P = I + A / c */
        for (j = 0; j < n; j++) P[i * n + j] = (i == j ? 1.0 : 0.0) + A[i * 2 + j] / c;
    for (i = 0; i < n; i++) {
        double b = 0.0;
        for (j = 0; j < n; j++) {
            double a = 0.0;
            for (k = 0; k < n; k++) a += Mi[i * n + k] * P[k * n + j];
            Ad[i * n + j] = a;
            b += Mi[i * n + j] * B[j] * (2.0 / c);
        }
        Bd[i] = b;
        Cd[i] = Mi[0 * n + i];                /* Cf M^-1 with Cf = [1, 0]: M^-1's first row */
    }
    *Dd = 0.5 * Bd[0];                        /* Df + Cf Bd / 2 */
    for (i = 0; i < n * n; i++)
        if (!isfinite(Ad[i])) return FPF_NONFINITE;
    for (i = 0; i < n; i++)
        if (!isfinite(Bd[i]) || !isfinite(Cd[i])) return FPF_NONFINITE;
    return isfinite(*Dd) ? FPF_OK : FPF_NONFINITE;
}

void fpf_error(const fpf_filter *f, const double *y, double *e)
{
    int k;
    for (k = 0; k < 3; k++)
        e[k] = f->kx * y[3 * k] + f->kp * y[3 * k + 1] + f->kd * y[3 * k + 2];
}

static double saturate(double F, double lim)
{
    if (F < -lim) F = -lim;
    if (F > lim) F = lim;
    return F;
}

int fpf_step(const fpf_filter *f, const double *Ad, const double *G, const double *e,
             double *xc, double *F)
{
    double x0, x1 = 0.0;
    if (!(isfinite(e[0]) && isfinite(e[1]) && isfinite(e[2]))) return FPF_NONFINITE;
    if (f->order == 0) {
        *F = saturate(-e[0], f->force_limit);
        return FPF_OK;
    }
    if (f->order == 1) {
        x0 = Ad[0] * xc[0] + G[0] * e[0] + G[1] * e[1] + G[2] * e[2];
    } else {
        x0 = Ad[0] * xc[0] + Ad[1] * xc[1] + G[0] * e[0] + G[1] * e[1] + G[2] * e[2];
        x1 = Ad[2] * xc[0] + Ad[3] * xc[1] + G[3] * e[0] + G[4] * e[1] + G[5] * e[2];
    }
    if (!isfinite(x0 + x1)) return FPF_NONFINITE;
    xc[0] = x0;
    if (f->order == 2) xc[1] = x1;
    *F = saturate(-x0, f->force_limit);
    return FPF_OK;
}

/* ------------------------------------------------------------------ continuous time (issue 24) */
/* The saturation's slope at v (fp_filter.h): 1 on the identity branch |v| <= lim, else 0. */
static double sat_slope(double v, double lim)
{
    return fabs(v) <= lim ? 1.0 : 0.0;
}

int fpf_rhs(const fpf_filter *f, const double *xc, double e, double *dxc)
{
    const double wc = f->cutoff;
    double d0, d1 = 0.0;
    if (f->order == 0) return isfinite(e) ? FPF_OK : FPF_NONFINITE;
    if (f->order == 1) {
        d0 = wc * (e - xc[0]);
    } else {
        d0 = xc[1];
        d1 = (wc * wc) * (e - xc[0]) - (2.0 * f->damping * wc) * xc[1];
    }
    if (!isfinite(d0) || !isfinite(d1)) return FPF_NONFINITE;
    dxc[0] = d0;
    if (f->order == 2) dxc[1] = d1;
    return FPF_OK;
}

int fpf_linearize(const fpf_filter *f, const double *xc, double e, double *A, double *B,
                  double *C, double *D)
{
    const int n = f->order;
    const double wc = f->cutoff, gains[3] = {f->kp, f->kd, f->kx};   /* phi_o, omega_o, x_o */
    double sigma;
    int i, k;
    if (n == 0) {
        if (!isfinite(e)) return FPF_NONFINITE;
        sigma = sat_slope(-e, f->force_limit);
        if (D != NULL)
            for (k = 0; k < 3; k++) D[k] = -sigma * gains[k];
        return FPF_OK;
    }
    for (i = 0; i < n; i++)
        if (!isfinite(xc[i])) return FPF_NONFINITE;
    sigma = sat_slope(-xc[0], f->force_limit);
    if (A != NULL) {
        if (n == 1) {
            A[0] = -wc;
        } else {
            A[0] = 0.0;
            A[1] = 1.0;
            A[2] = -(wc * wc);
            A[3] = -2.0 * f->damping * wc;
        }
    }
    if (B != NULL) {
        const double bf = n == 1 ? wc : wc * wc;     /* Bf = [wc] or [0, wc^2] */
        for (k = 0; k < 3; k++) {
            B[k] = n == 1 ? bf * gains[k] : 0.0;
            if (n == 2) B[3 + k] = bf * gains[k];
        }
    }
    if (C != NULL) {
        C[0] = -sigma;
        if (n == 2) C[1] = 0.0;
    }
    if (D != NULL)
        for (k = 0; k < 3; k++) D[k] = 0.0;
    return FPF_OK;
}

int fpf_output_derivatives(const fpf_filter *f, const double *xc, const double *e, double *d)
{
    const double wc = f->cutoff;
    double v[5], sigma;
    int k;
    if (f->order == 0) {                 /* F_c = -sat(e): e's derivatives; e''', e'''' are 0 */
        v[0] = e[0];
        v[1] = e[1];
        v[2] = e[2];
        v[3] = 0.0;
        v[4] = 0.0;
    } else if (f->order == 1) {          /* v' = wc (e - v), differentiated */
        v[0] = xc[0];
        v[1] = wc * (e[0] - xc[0]);
        v[2] = wc * (e[1] - v[1]);
        v[3] = wc * (e[2] - v[2]);
        v[4] = wc * (0.0 - v[3]);
    } else {                             /* v'' = wc^2 (e - v) - 2 zeta wc v', differentiated */
        v[0] = xc[0];
        v[1] = xc[1];
        v[2] = (wc * wc) * (e[0] - xc[0]) - (2.0 * f->damping * wc) * xc[1];
        v[3] = (wc * wc) * (e[1] - v[1]) - (2.0 * f->damping * wc) * v[2];
        v[4] = (wc * wc) * (e[2] - v[2]) - (2.0 * f->damping * wc) * v[3];
    }
    for (k = 0; k < 5; k++)
        if (!isfinite(v[k])) return FPF_NONFINITE;
    if (!(isfinite(e[0]) && isfinite(e[1]) && isfinite(e[2]))) return FPF_NONFINITE;
    sigma = sat_slope(-v[0], f->force_limit);
    for (k = 0; k < 4; k++) d[k] = -sigma * v[k + 1];
    return FPF_OK;
}
