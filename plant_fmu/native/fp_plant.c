/*
 * fp_plant.c - the compiled kernel of the plant (see fp_plant.h for the contract).
 *
 * Each function computes exactly what its numpy counterpart in plant_fmu/dynamics.py computes,
 * and the loops do what plant_fmu/integrators/rk.py does, in the same order of operations where
 * that order decides the result (tests/common/test_kernels.py holds them to 1e-12).
 */
#include "fp_plant.h"

#include <math.h>
#include <stddef.h>

#ifndef FP_SOURCE_DIGEST
#define FP_SOURCE_DIGEST "unknown"
#endif

/* The step-size control of rk.py (scipy's constants). */
#define SAFETY 0.9
#define MIN_FACTOR 0.2
#define MAX_FACTOR 10.0

/* ---------------------------------------------------------------------- subnormals
 * A decayed state holds numbers below 2.2e-308 (products of small angles and rates), whose
 * arithmetic costs x86 cores about 100 cycles an operation: a step of the decayed filtered
 * scene cost 1.6 times more (bench/bench_long_run.py). The steppers run with subnormal results
 * and operands flushed to zero (MXCSR's FTZ and DAZ; FPCR's FZ on AArch64): a change below
 * 2.2e-308 in absolute terms, where the state is at least 1e-300 or zero anyway. The caller's
 * floating-point mode is put back on return (its exception flags keep what was raised). */
#if defined(__SSE2__) || defined(_M_X64) || defined(_M_AMD64)
#include <xmmintrin.h>
typedef unsigned int fp_fenv;
#define FP_MXCSR_FTZ_DAZ 0x8040u
#define FP_MXCSR_FLAGS 0x003Fu
static fp_fenv ftz_enter(void)
{
    fp_fenv old = _mm_getcsr();
    _mm_setcsr(old | FP_MXCSR_FTZ_DAZ);
    return old;
}
static void ftz_leave(fp_fenv old)
{
    _mm_setcsr((old & ~FP_MXCSR_FLAGS) | (_mm_getcsr() & FP_MXCSR_FLAGS));
}
#elif defined(__aarch64__) && defined(__GNUC__)
typedef unsigned long fp_fenv;
static fp_fenv ftz_enter(void)
{
    fp_fenv old;
    __asm__ __volatile__("mrs %0, fpcr" : "=r"(old));
    __asm__ __volatile__("msr fpcr, %0" : : "r"(old | (1ul << 24)));
    return old;
}
static void ftz_leave(fp_fenv old) { __asm__ __volatile__("msr fpcr, %0" : : "r"(old)); }
#else
typedef int fp_fenv;
static fp_fenv ftz_enter(void) { return 0; }
static void ftz_leave(fp_fenv old) { (void)old; }
#endif

/* The compiler does not know that arithmetic depends on the floating-point mode: a stepper that
 * runs flushed and the wrapper that switches the mode are never inlined (not even by link-time
 * optimisation, into a caller in another file), so that no arithmetic of the caller moves into
 * the flushed window and none of the stepper's out of it. */
#if defined(__GNUC__)
#define FP_NOINLINE __attribute__((noinline))
#elif defined(_MSC_VER)
#define FP_NOINLINE __declspec(noinline)
#else
#define FP_NOINLINE
#endif

/* Whether times x and y may be flushed: neither is itself subnormal (a step of 5e-324 s from
 * t = 0 is a legal step, which the flushed arithmetic would take as none). */
static int flushable(double x, double y)
{
    return (x == 0.0 || !isfinite(x) || fabs(x) >= 2.2250738585072014e-308) &&
           (y == 0.0 || !isfinite(y) || fabs(y) >= 2.2250738585072014e-308);
}

int fp_plant_abi(void) { return FP_PLANT_ABI; }

const char *fp_plant_source_digest(void) { return FP_SOURCE_DIGEST; }

static int finite_array(const double *a, long n)
{
    long i;
    if (n > 0 && a == NULL) return 0;
    for (i = 0; i < n; i++)
        if (!isfinite(a[i])) return 0;
    return 1;
}

int fp_plant_prepare(fp_plant *p)
{
    int j, n;
    if (p == NULL || p->n < 0 || p->n > 100000) return FP_BADARG;
    n = p->n;
    if (!(isfinite(p->I0) && isfinite(p->I1) && isfinite(p->I2) && isfinite(p->g)))
        return FP_BADARG;
    if (!finite_array(p->I3, n) || !finite_array(p->I5, n) || !finite_array(p->K, n)
        || !finite_array(p->D, n) || !finite_array(p->tip_slope, n)
        || !finite_array(p->tip_defl, n))
        return FP_BADARG;
    if (p->preload && !finite_array(p->Kg, (long)n * n)) return FP_BADARG;
    if (p->stiffened && (p->linear || (n > 0 && !p->preload) || n + 2 > FP_STIFF_NQMAX
                         || p->npts < 1
                         || !finite_array(p->pts, (long)p->npts * (2 + n + n * n))))
        return FP_BADARG;
    p->stiffened = p->stiffened != 0;
    p->preload = (p->preload != 0) && n > 0;
    p->linear = p->linear != 0;
    p->nx = 2 * (n + 2);
    p->I3I3 = p->I3I5 = p->I5I5 = 0.0;
    for (j = 0; j < n; j++) {
        p->I3I3 += p->I3[j] * p->I3[j];
        p->I3I5 += p->I3[j] * p->I5[j];
        p->I5I5 += p->I5[j] * p->I5[j];
    }
    return FP_OK;
}

long fp_work_size(const fp_plant *p, int stages)
{
    if (p == NULL || stages < 1) return 0;
    return (long)(stages + 2) * p->nx;
}

/* ------------------------------------------------------------------ built-in tableaus */
static const double EULER_A[1] = {0.0};
static const double EULER_B[1] = {1.0};
static const double EULER_C[1] = {0.0};

static const double RK4_A[16] = {0.0, 0.0, 0.0, 0.0,
                                 0.5, 0.0, 0.0, 0.0,
                                 0.0, 0.5, 0.0, 0.0,
                                 0.0, 0.0, 1.0, 0.0};
static const double RK4_B[4] = {1.0 / 6, 1.0 / 3, 1.0 / 3, 1.0 / 6};
static const double RK4_C[4] = {0.0, 0.5, 0.5, 1.0};

static const double DP_A[49] = {
    0, 0, 0, 0, 0, 0, 0,
    1.0 / 5, 0, 0, 0, 0, 0, 0,
    3.0 / 40, 9.0 / 40, 0, 0, 0, 0, 0,
    44.0 / 45, -56.0 / 15, 32.0 / 9, 0, 0, 0, 0,
    19372.0 / 6561, -25360.0 / 2187, 64448.0 / 6561, -212.0 / 729, 0, 0, 0,
    9017.0 / 3168, -355.0 / 33, 46732.0 / 5247, 49.0 / 176, -5103.0 / 18656, 0, 0,
    35.0 / 384, 0, 500.0 / 1113, 125.0 / 192, -2187.0 / 6784, 11.0 / 84, 0};
static const double DP_B[7] = {35.0 / 384, 0, 500.0 / 1113, 125.0 / 192, -2187.0 / 6784,
                               11.0 / 84, 0};
static const double DP_C[7] = {0, 1.0 / 5, 3.0 / 10, 4.0 / 5, 8.0 / 9, 1, 1};
/* E = B - B_hat, each entry rounded once from the two rounded weights, as numpy does */
#define DP_E(b, bh) ((double)(b) - (double)(bh))
static const double DP_E_[7] = {
    DP_E(35.0 / 384, 5179.0 / 57600), DP_E(0, 0), DP_E(500.0 / 1113, 7571.0 / 16695),
    DP_E(125.0 / 192, 393.0 / 640), DP_E(-2187.0 / 6784, -92097.0 / 339200),
    DP_E(11.0 / 84, 187.0 / 2100), DP_E(0, 1.0 / 40)};

static const fp_tableau TABLEAUS[3] = {
    {1, EULER_A, EULER_B, EULER_C, NULL, 0},
    {4, RK4_A, RK4_B, RK4_C, NULL, 0},
    {7, DP_A, DP_B, DP_C, DP_E_, 1},
};

const fp_tableau *fp_builtin_tableau(int method)
{
    if (method < FP_EULER || method > FP_DOPRI5) return NULL;
    return &TABLEAUS[method];
}

/* ------------------------------------------------------------------ right-hand side */
/* The nonlinear model: dynamics.py, PlantModel.forces and .accelerations (Schur complement of the
 * identity block of the mass-normalised modes, O(n), or O(n^2) with the preload). */
static void rhs_nonlinear(const fp_plant *p, const double *x, double u, double *out)
{
    const int n = p->n, nq = n + 2;
    const double *I3 = p->I3, *I5 = p->I5;
    const double phi = x[1], phid = x[nq + 1];
    const double c = cos(phi), s = sin(phi);
    double I3eta = 0.0, I3etad = 0.0, ee = 0.0, eed = 0.0;
    double f0, f1, I3fe = 0.0, I5fe = 0.0, a00, a01, a11, r0, r1, det, xdd, phidd;
    int i, j, k;
    for (j = 0; j < n; j++) {
        const double e = x[2 + j], ed = x[nq + 2 + j];
        I3eta += I3[j] * e;
        I3etad += I3[j] * ed;
        ee += e * e;
        eed += e * ed;
    }
    f0 = u - (p->I1 * s + I3eta * c) * phid * phid - 2.0 * phid * s * I3etad;
    f1 = -2.0 * phid * eed + p->g * (p->I1 * s + I3eta * c);
    for (j = 0; j < n; j++) {
        const double e = x[2 + j];
        double fe = phid * phid * e + p->g * s * I3[j] - p->K[j] * e - p->D[j] * x[nq + 2 + j];
        if (p->preload) {
            double kge = 0.0;
            const double *row = p->Kg + (size_t)j * n;
            for (k = 0; k < n; k++) kge += row[k] * x[2 + k];
            fe += c * kge;
            f1 -= 0.5 * s * e * kge;
        }
        out[nq + 2 + j] = fe;
        I3fe += I3[j] * fe;
        I5fe += I5[j] * fe;
    }
    a00 = p->I0 - c * c * p->I3I3;
    a01 = -p->I1 * c + s * I3eta + c * p->I3I5;
    a11 = p->I2 + ee - p->I5I5;
    r0 = f0 + c * I3fe;
    r1 = f1 - I5fe;
    det = a00 * a11 - a01 * a01;
    xdd = (a11 * r0 - a01 * r1) / det;
    phidd = (a00 * r1 - a01 * r0) / det;
    for (i = 0; i < nq; i++) out[i] = x[nq + i];
    out[nq] = xdd;
    out[nq + 1] = phidd;
    for (j = 0; j < n; j++) out[nq + 2 + j] += c * xdd * I3[j] - phidd * I5[j];
}

/* The linearised model M0 qdd + D0 qd + K0 q = e_x u (dynamics.py, PlantModel.linearize), solved
 * by the same Schur complement at phi = 0, eta = 0. */
static void rhs_linear(const fp_plant *p, const double *x, double u, double *out)
{
    const int n = p->n, nq = n + 2;
    const double *I3 = p->I3, *I5 = p->I5;
    const double phi = x[1];
    double I3eta = 0.0, f1, I3fe = 0.0, I5fe = 0.0, a00, a01, a11, r0, r1, det, xdd, phidd;
    int i, j, k;
    for (j = 0; j < n; j++) I3eta += I3[j] * x[2 + j];
    f1 = p->g * (p->I1 * phi + I3eta);
    for (j = 0; j < n; j++) {
        const double e = x[2 + j];
        double fe = p->g * phi * I3[j] - p->K[j] * e - p->D[j] * x[nq + 2 + j];
        if (p->preload) {
            double kge = 0.0;
            const double *row = p->Kg + (size_t)j * n;
            for (k = 0; k < n; k++) kge += row[k] * x[2 + k];
            fe += kge;
        }
        out[nq + 2 + j] = fe;
        I3fe += I3[j] * fe;
        I5fe += I5[j] * fe;
    }
    a00 = p->I0 - p->I3I3;
    a01 = -p->I1 + p->I3I5;
    a11 = p->I2 - p->I5I5;
    r0 = u + I3fe;
    r1 = f1 - I5fe;
    det = a00 * a11 - a01 * a01;
    xdd = (a11 * r0 - a01 * r1) / det;
    phidd = (a00 * r1 - a01 * r0) / det;
    for (i = 0; i < nq; i++) out[i] = x[nq + i];
    out[nq] = xdd;
    out[nq + 1] = phidd;
    for (j = 0; j < n; j++) out[nq + 2 + j] += xdd * I3[j] - phidd * I5[j];
}

/* The stiffened model: dynamics.py, StiffenedPlantModel. M and f of the nonlinear model with the
 * preload (PlantModel.mass_matrix, .forces), plus the foreshortening's kinetic terms over the mass
 * points (Kane's: sum m_p (J J^T - J0 J0^T) and sum m_p (J r - J0 r0) along b1 and b2), solved by
 * Cholesky. */
static const double *stiff_point(const fp_plant *p, int k, double *sp, double *mp,
                                 const double **N)
{
    const int n = p->n;
    const double *pt = p->pts + (size_t)k * (2 + n + n * n);
    *sp = pt[0];
    *mp = pt[1];
    *N = pt + 2;
    return pt + 2 + n;
}

/* One point's rows of J along b1 and b2 with u (J1, J2) and without (J01, J02; only the columns
 * that differ: J1[2..] = -G eta, J2[1] = s_p - u), and -c_p with and without u. */
typedef struct stiff_pt {
    double m, J1[FP_STIFF_NQMAX], J2[FP_STIFF_NQMAX], J01[FP_STIFF_NQMAX], J02[FP_STIFF_NQMAX];
    double r1, r2, r01, r02;
} stiff_pt;

static void stiff_rows(const fp_plant *p, const double *x, int k, double c, double s,
                       stiff_pt *P)
{
    const int n = p->n, nq = n + 2;
    const double phid = x[nq + 1];
    double sp, w = 0.0, wd = 0.0, u = 0.0, ud = 0.0, eGe = 0.0;
    const double *N, *G = stiff_point(p, k, &sp, &P->m, &N);
    int i, j;
    for (i = 0; i < n; i++) {
        const double *row = G + (size_t)i * n;
        double ge = 0.0, ged = 0.0;
        for (j = 0; j < n; j++) {
            ge += row[j] * x[2 + j];
            ged += row[j] * x[nq + 2 + j];
        }
        w += N[i] * x[2 + i];
        wd += N[i] * x[nq + 2 + i];
        u += 0.5 * ge * x[2 + i];
        ud += ge * x[nq + 2 + i];
        eGe += ged * x[nq + 2 + i];
        P->J1[2 + i] = -ge;
        P->J01[2 + i] = 0.0;
        P->J2[2 + i] = P->J02[2 + i] = N[i];
    }
    P->J1[0] = P->J01[0] = -s;
    P->J1[1] = P->J01[1] = -w;
    P->J2[0] = P->J02[0] = -c;
    P->J2[1] = sp - u;
    P->J02[1] = sp;
    P->r01 = 2.0 * wd * phid + sp * phid * phid;
    P->r02 = w * phid * phid;
    P->r1 = eGe + 2.0 * wd * phid + (sp - u) * phid * phid;
    P->r2 = 2.0 * ud * phid + w * phid * phid;
}

static void rhs_stiffened(const fp_plant *p, const double *x, double u, double *out)
{
    const int n = p->n, nq = n + 2;
    const double *I3 = p->I3, *I5 = p->I5;
    const double phid = x[nq + 1], c = cos(x[1]), s = sin(x[1]);
    double M[FP_STIFF_NQMAX * FP_STIFF_NQMAX], f[FP_STIFF_NQMAX];
    double I3eta = 0.0, I3etad = 0.0, ee = 0.0, eed = 0.0;
    stiff_pt P;
    int i, j, k;
    /* the nonlinear model with the preload (upper triangle of M) */
    for (i = 0; i < nq * nq; i++) M[i] = 0.0;
    for (j = 0; j < n; j++) {
        const double e = x[2 + j], ed = x[nq + 2 + j];
        const double *row = p->Kg + (size_t)j * n;
        double kge = 0.0;
        for (k = 0; k < n; k++) kge += row[k] * x[2 + k];
        I3eta += I3[j] * e;
        I3etad += I3[j] * ed;
        ee += e * e;
        eed += e * ed;
        f[2 + j] = phid * phid * e + p->g * s * I3[j] - p->K[j] * e - p->D[j] * ed + c * kge;
        M[0 * nq + 2 + j] = -c * I3[j];
        M[1 * nq + 2 + j] = I5[j];
        M[(2 + j) * nq + 2 + j] = 1.0;
    }
    f[0] = u - (p->I1 * s + I3eta * c) * phid * phid - 2.0 * phid * s * I3etad;
    f[1] = -2.0 * phid * eed + p->g * (p->I1 * s + I3eta * c);
    for (j = 0; j < n; j++) {
        const double *row = p->Kg + (size_t)j * n;
        double kge = 0.0;
        for (k = 0; k < n; k++) kge += row[k] * x[2 + k];
        f[1] -= 0.5 * s * x[2 + j] * kge;
    }
    M[0] = p->I0;
    M[1] = -p->I1 * c + s * I3eta;
    M[nq + 1] = p->I2 + ee;
    /* the foreshortening's kinetic terms */
    for (k = 0; k < p->npts; k++) {
        stiff_rows(p, x, k, c, s, &P);
        for (i = 0; i < nq; i++) {
            f[i] += P.m * (P.J1[i] * P.r1 + P.J2[i] * P.r2 - P.J01[i] * P.r01
                           - P.J02[i] * P.r02);
            for (j = i; j < nq; j++)
                M[i * nq + j] += P.m * (P.J1[i] * P.J1[j] + P.J2[i] * P.J2[j]
                                        - P.J01[i] * P.J01[j] - P.J02[i] * P.J02[j]);
        }
    }
    /* Cholesky M = R^T R in the upper triangle, then R^T y = f, R a = y (a into f) */
    for (i = 0; i < nq; i++) {
        double d = M[i * nq + i];
        for (k = 0; k < i; k++) d -= M[k * nq + i] * M[k * nq + i];
        d = sqrt(d);                               /* NaN if M is not positive definite */
        M[i * nq + i] = d;
        for (j = i + 1; j < nq; j++) {
            double v = M[i * nq + j];
            for (k = 0; k < i; k++) v -= M[k * nq + i] * M[k * nq + j];
            M[i * nq + j] = v / d;
        }
    }
    for (i = 0; i < nq; i++) {
        for (k = 0; k < i; k++) f[i] -= M[k * nq + i] * f[k];
        f[i] /= M[i * nq + i];
    }
    for (i = nq - 1; i >= 0; i--) {
        for (k = i + 1; k < nq; k++) f[i] -= M[i * nq + k] * f[k];
        f[i] /= M[i * nq + i];
    }
    for (i = 0; i < nq; i++) {
        out[i] = x[nq + i];
        out[nq + i] = f[i];
    }
}

/* The foreshortening's kinetic energy (StiffenedPlantModel.energy_numpy's dT). */
static double stiffened_dT(const fp_plant *p, const double *x, double c, double s)
{
    const int nq = p->n + 2;
    double dT = 0.0;
    stiff_pt P;
    int i, k;
    for (k = 0; k < p->npts; k++) {
        double v1 = 0.0, v2 = 0.0, v01 = 0.0, v02 = 0.0;
        stiff_rows(p, x, k, c, s, &P);
        for (i = 0; i < nq; i++) {
            v1 += P.J1[i] * x[nq + i];
            v2 += P.J2[i] * x[nq + i];
            v01 += P.J01[i] * x[nq + i];
            v02 += P.J02[i] * x[nq + i];
        }
        dT += 0.5 * P.m * (v1 * v1 + v2 * v2 - v01 * v01 - v02 * v02);
    }
    return dT;
}

void fp_rhs(const fp_plant *p, const double *x, double u, double *dx)
{
    if (p->linear)
        rhs_linear(p, x, u, dx);
    else if (p->stiffened)
        rhs_stiffened(p, x, u, dx);
    else
        rhs_nonlinear(p, x, u, dx);
}

/* ------------------------------------------------------------------ outputs */
double fp_energy(const fp_plant *p, const double *x)
{
    const int n = p->n, nq = n + 2;
    const double *I3 = p->I3, *I5 = p->I5;
    const double phi = x[1], xd = x[nq], phid = x[nq + 1];
    double I3eta = 0.0, I3etad = 0.0, ee = 0.0, I5etad = 0.0, etadetad = 0.0, strain = 0.0;
    double T, V, ekge = 0.0;
    int j, k;
    for (j = 0; j < n; j++) {
        const double e = x[2 + j], ed = x[nq + 2 + j];
        I3eta += I3[j] * e;
        I3etad += I3[j] * ed;
        ee += e * e;
        I5etad += I5[j] * ed;
        etadetad += ed * ed;
        strain += p->K[j] * e * e;
    }
    if (p->preload)
        for (j = 0; j < n; j++) {
            const double *row = p->Kg + (size_t)j * n;
            for (k = 0; k < n; k++) ekge += x[2 + j] * row[k] * x[2 + k];
        }
    if (p->linear) {
        /* 1/2 qd.M0.qd + 1/2 q.K0.q + g I1 (LinearPlantModel.energy) */
        T = 0.5 * (p->I0 * xd * xd - 2.0 * p->I1 * xd * phid - 2.0 * xd * I3etad
                   + p->I2 * phid * phid + 2.0 * phid * I5etad + etadetad);
        V = 0.5 * (-p->g * p->I1 * phi * phi - 2.0 * p->g * phi * I3eta + strain - ekge)
            + p->g * p->I1;
        return T + V;
    }
    {
        const double c = cos(phi), s = sin(phi);
        T = (0.5 * p->I0 * xd * xd + xd * (-(p->I1 * phid + I3etad) * c + phid * s * I3eta)
             + 0.5 * phid * phid * (p->I2 + ee) + phid * I5etad + 0.5 * etadetad);
        V = p->g * (p->I1 * c - s * I3eta) + 0.5 * strain;
        if (p->preload) V -= 0.5 * c * ekge;
        if (p->stiffened) T += stiffened_dT(p, x, c, s);
        return T + V;
    }
}

void fp_tip(const fp_plant *p, const double *x, double *tip)
{
    const int n = p->n, nq = n + 2;
    double sl = 0.0, sld = 0.0;
    int j;
    for (j = 0; j < n; j++) {
        sl += p->tip_slope[j] * x[2 + j];
        sld += p->tip_slope[j] * x[nq + 2 + j];
    }
    if (p->linear) {
        tip[0] = x[1] + sl;
        tip[1] = x[nq + 1] + sld;
    } else if (n == 0) {
        tip[0] = x[1];
        tip[1] = x[nq + 1];
    } else {
        tip[0] = x[1] + atan(sl);
        tip[1] = x[nq + 1] + sld / (1.0 + sl * sl);
    }
}

void fp_outputs(const fp_plant *p, const double *x, int want_energy, double *out)
{
    const int n = p->n, nq = n + 2;
    double tip = 0.0;
    int j;
    fp_tip(p, x, out + FP_OUT_PHI_O);
    out[FP_OUT_X] = x[0];
    out[FP_OUT_XDOT] = x[nq];
    out[FP_OUT_PHI] = x[1];
    for (j = 0; j < n; j++) {
        tip += p->tip_defl[j] * x[2 + j];
        out[FP_OUT_ETA + j] = x[2 + j];
    }
    out[FP_OUT_TIP] = tip;
    if (want_energy) out[FP_OUT_ENERGY] = fp_energy(p, x);
}

/* ------------------------------------------------------------------ the loops */
/* The input at the time offset st from tu (plant_fmu.integrators.base.Stepper._u_at). */
static double input_at(const fp_input *u, double st)
{
    if (u->du != 0.0 || u->d2u != 0.0) return u->u0 + st * (u->du + 0.5 * st * u->d2u);
    return u->u0;
}

/* 1 if every entry of y is finite. As the Python loop: a sum of squares that is finite settles it
 * at once; otherwise (overflow or NaN) each entry is looked at. */
static int all_finite(const double *y, int nx)
{
    double norm2 = 0.0;
    int m;
    for (m = 0; m < nx; m++) norm2 += y[m] * y[m];
    if (norm2 < HUGE_VAL) return 1;
    for (m = 0; m < nx; m++)
        if (!(fabs(y[m]) < HUGE_VAL)) return 0;
    return 1;
}

static int check_tableau(const fp_tableau *tab)
{
    return tab != NULL && tab->stages >= 1 && tab->stages <= 64 && tab->A != NULL
           && tab->B != NULL && tab->C != NULL;
}

/* The explicit Runge-Kutta loop below for a tableau of at most SPARSE_STAGES stages, with its
 * products h a_ij and h b_i formed once per call and its zero coefficients skipped (RK4 has 3
 * nonzero a_ij of 6): the same sums as the loop below, bit for bit. Each sum still starts from
 * 0.0 and adds its terms in the order of j; a skipped term is (h 0) K, a zero of either sign
 * while K is finite, which leaves a sum begun at +0.0 unchanged (0.0 + -0.0 is +0.0), so it
 * differs from the loop's only where a K is already infinite or NaN, and then both end the
 * substep with FP_NONFINITE (every b_i of a tableau that reaches that K is nonzero, or the
 * stage is unused) with y unchanged. */
#define SPARSE_STAGES 8

/* ys = y + (0.0 + a_0 K_c0 + ... + a_{n-1} K_c{n-1}), the sum taken left to right as the loop
 * over j does it, with its zero-, one-, two- and four-term cases (RK4's stages and its sum)
 * written out so that the loop over the entries has no inner loop: the same operations in the
 * same order, bit for bit. */
static void stage_sum(const double *y, const double *K, int nx, const double *a, const int *c,
                      int n, double *ys)
{
    int m, j;
    if (n == 0) {
        for (m = 0; m < nx; m++) ys[m] = y[m] + 0.0;
    } else if (n == 1) {
        const double a0 = a[0], *K0 = K + (size_t)c[0] * nx;
        for (m = 0; m < nx; m++) ys[m] = y[m] + (0.0 + a0 * K0[m]);
    } else if (n == 2) {
        const double a0 = a[0], a1 = a[1];
        const double *K0 = K + (size_t)c[0] * nx, *K1 = K + (size_t)c[1] * nx;
        for (m = 0; m < nx; m++) ys[m] = y[m] + ((0.0 + a0 * K0[m]) + a1 * K1[m]);
    } else if (n == 4) {
        const double a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3];
        const double *K0 = K + (size_t)c[0] * nx, *K1 = K + (size_t)c[1] * nx;
        const double *K2 = K + (size_t)c[2] * nx, *K3 = K + (size_t)c[3] * nx;
        for (m = 0; m < nx; m++)
            ys[m] = y[m] + ((((0.0 + a0 * K0[m]) + a1 * K1[m]) + a2 * K2[m]) + a3 * K3[m]);
    } else {
        for (m = 0; m < nx; m++) {
            double acc = 0.0;
            for (j = 0; j < n; j++) acc += a[j] * K[(size_t)c[j] * nx + m];
            ys[m] = y[m] + acc;
        }
    }
}

static int sparse_steps(const fp_plant *p, const fp_tableau *tab, const fp_input *u, double t,
                        double h, long n_steps, double *y, double *work, long *done)
{
    const int nx = p->nx, s = tab->stages;
    const double s0 = t - u->tu;
    double *ys = work, *K = work + nx;
    double ha[SPARSE_STAGES * SPARSE_STAGES], hb[SPARSE_STAGES], ch[SPARSE_STAGES];
    int col[SPARSE_STAGES * SPARSE_STAGES], n_a[SPARSE_STAGES], colb[SPARSE_STAGES], n_b = 0;
    long k;
    int i, j, m;
    for (i = 0; i < s; i++) {
        n_a[i] = 0;
        for (j = 0; j < i; j++)
            if (tab->A[i * s + j] != 0.0) {
                col[i * SPARSE_STAGES + n_a[i]] = j;
                ha[i * SPARSE_STAGES + n_a[i]++] = h * tab->A[i * s + j];
            }
        if (tab->B[i] != 0.0) {
            colb[n_b] = i;
            hb[n_b++] = h * tab->B[i];
        }
        ch[i] = tab->C[i] * h;
    }
    for (k = 0; k < n_steps; k++) {
        const double sk = s0 + k * h;
        for (i = 0; i < s; i++) {
            stage_sum(y, K, nx, ha + i * SPARSE_STAGES, col + i * SPARSE_STAGES, n_a[i], ys);
            fp_rhs(p, ys, input_at(u, sk + ch[i]), K + (size_t)i * nx);
        }
        stage_sum(y, K, nx, hb, colb, n_b, ys);
        if (!all_finite(ys, nx)) return FP_NONFINITE;
        for (m = 0; m < nx; m++) y[m] = ys[m];
        *done = k + 1;
    }
    return FP_OK;
}

FP_NOINLINE
static int fixed_steps_(const fp_plant *p, int method, const fp_tableau *tab, const fp_input *u,
                   double t, double h, long n_steps, double *y, double *work, long *done)
{
    const int nx = p->nx, nq = p->nx / 2;
    const double s0 = t - u->tu;
    double *ys = work, *K = work + nx;
    long k;
    int i, j, m;
    *done = 0;
    if (n_steps < 0 || !(h > 0.0) || !isfinite(h) || y == NULL || work == NULL) return FP_BADARG;
    if (method == FP_SYMPLECTIC_EULER) {
        for (k = 0; k < n_steps; k++) {
            fp_rhs(p, y, input_at(u, s0 + k * h), K);
            for (m = nq; m < nx; m++) ys[m] = y[m] + h * K[m];      /* qd + h qdd */
            for (m = 0; m < nq; m++) ys[m] = y[m] + h * ys[nq + m];  /* q + h qd_new */
            if (!all_finite(ys, nx)) return FP_NONFINITE;
            for (m = 0; m < nx; m++) y[m] = ys[m];
            *done = k + 1;
        }
        return FP_OK;
    }
    if (!check_tableau(tab)) return FP_BADARG;
    if (tab->stages <= SPARSE_STAGES) return sparse_steps(p, tab, u, t, h, n_steps, y, work, done);
    for (k = 0; k < n_steps; k++) {
        const int s = tab->stages;
        for (i = 0; i < s; i++) {
            double st, acc;
            for (m = 0; m < nx; m++) {
                acc = 0.0;
                for (j = 0; j < i; j++) acc += (h * tab->A[i * s + j]) * K[(size_t)j * nx + m];
                ys[m] = y[m] + acc;
            }
            st = s0 + k * h + tab->C[i] * h;
            fp_rhs(p, ys, input_at(u, st), K + (size_t)i * nx);
        }
        for (m = 0; m < nx; m++) {
            double acc = 0.0;
            for (i = 0; i < s; i++) acc += (h * tab->B[i]) * K[(size_t)i * nx + m];
            ys[m] = y[m] + acc;
        }
        if (!all_finite(ys, nx)) return FP_NONFINITE;
        for (m = 0; m < nx; m++) y[m] = ys[m];
        *done = k + 1;
    }
    return FP_OK;
}

/* One FSAL step of the tableau from (t, y) over h: K[0] = f; the stages K[1..s-1]; y_new = the
 * last stage's argument (the last row of A is B); f_new = K[s-1] = f(t + h, y_new). */
static void fsal_step(const fp_plant *p, const fp_tableau *tab, const fp_input *u, double t,
                      const double *y, double h, const double *f, double *K, double *ys)
{
    const int nx = p->nx, s = tab->stages;
    int i, j, m;
    for (m = 0; m < nx; m++) K[m] = f[m];
    for (i = 1; i < s; i++) {
        const double ch = tab->C[i] * h;
        for (m = 0; m < nx; m++) {
            double acc = 0.0;
            for (j = 0; j < i; j++) acc += (h * tab->A[i * s + j]) * K[(size_t)j * nx + m];
            ys[m] = y[m] + acc;
        }
        fp_rhs(p, ys, input_at(u, (t + ch) - u->tu), K + (size_t)i * nx);
    }
}

FP_NOINLINE
static int dopri_advance_(const fp_plant *p, const fp_tableau *tab, const fp_input *u, double *t,
                     double t_end, double *y, double *f, fp_adaptive *a, double *work)
{
    const int nx = p->nx;
    const double err_exp = -1.0 / 5.0;    /* -1 / (error order 4 + 1) */
    double *ys = work, *K;
    long taken = 0;
    int i, m;
    if (!check_tableau(tab) || tab->E == NULL || !tab->fsal || a == NULL || t == NULL
        || y == NULL || f == NULL || work == NULL || !(a->rtol >= 0.0)
        || !(a->n_atol == 1 || a->n_atol == nx) || a->atol == NULL || !(a->max_step > 0.0)
        || !(a->min_step >= 0.0) || a->max_steps < 1 || !(a->h_abs > 0.0) || isnan(t_end))
        return FP_BADARG;
    K = work + nx;                         /* the last stage's argument ys is y_new */
    while (*t < t_end) {
        const double t0 = *t;
        const int s = tab->stages;
        double min_step = 10.0 * (nextafter(t0, HUGE_VAL) - t0);
        double h_abs = a->h_abs, h, t_new;
        int rejected = 0;
        if (taken >= a->max_steps) return FP_CAP;
        if (a->min_step > min_step) min_step = a->min_step;
        if (t_end - t0 <= min_step) {          /* a rounding remainder: nothing to integrate */
            *t = t_end;
            return FP_OK;
        }
        for (;;) {
            double remaining, err2, error_norm, factor;
            if (h_abs < min_step) {
                a->fail_h = h_abs;
                a->fail_min_step = min_step;
                return FP_UNDERFLOW;
            }
            remaining = t_end - t0;
            if (h_abs >= remaining) {
                h = remaining;
                t_new = t_end;
            } else if (2.0 * h_abs > remaining) {   /* avoid a tiny last step: split the rest */
                h = 0.5 * remaining;
                t_new = t0 + h;
            } else {
                h = h_abs;
                t_new = t0 + h_abs;
            }
            fsal_step(p, tab, u, t0, y, h, f, K, ys);
            a->nfev += s - 1;
            err2 = 0.0;
            for (m = 0; m < nx; m++) {
                double e = 0.0, sc = fabs(y[m]);
                for (i = 0; i < s; i++) e += K[(size_t)i * nx + m] * tab->E[i];
                if (fabs(ys[m]) > sc || isnan(ys[m])) sc = fabs(ys[m]);
                sc = sc * a->rtol + a->atol[a->n_atol == 1 ? 0 : m];
                e /= sc;
                err2 += e * e;
            }
            error_norm = h * sqrt(err2 / nx);
            if (error_norm < 1.0) {
                double h_next;
                if (error_norm == 0.0)
                    factor = MAX_FACTOR;
                else {
                    factor = SAFETY * pow(error_norm, err_exp);
                    if (factor > MAX_FACTOR) factor = MAX_FACTOR;
                }
                if (rejected && factor > 1.0) factor = 1.0;
                h_next = h * factor;
                if (h < h_abs && !rejected && h_next < h_abs) h_next = h_abs;
                a->h_abs = h_next < a->max_step ? h_next : a->max_step;
                for (m = 0; m < nx; m++) {
                    y[m] = ys[m];
                    f[m] = K[(size_t)(s - 1) * nx + m];
                }
                *t = t_new;
                a->nsteps++;
                taken++;
                break;
            }
            if (isnan(error_norm) || error_norm == HUGE_VAL)
                factor = MIN_FACTOR;
            else {
                factor = SAFETY * pow(error_norm, err_exp);
                if (factor < MIN_FACTOR) factor = MIN_FACTOR;
            }
            h_abs = h * factor;
            rejected = 1;
            a->nrejected++;
        }
    }
    return FP_OK;
}

/* ------------------------------------------------------------------ Jacobians and output
 * derivatives (issue 24). With z a state or the force, d qdd/dz = M^-1 (df/dz - (dM/dz) qdd)
 * (dynamics.py, PlantModel.jacobian_numpy): the vector r = df/dz - (dM/dz) qdd is formed by hand
 * for one column (or one direction) and solved by the Schur complement of the rhs. */

/* 1 if every a[i] is finite: a - a is 0 for a finite a and NaN for an infinity or a NaN; four
 * independent sums (the check is a quarter of a Jacobian's cost with a branch per entry). */
static int all_finite_n(const double *a, long n)
{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    long i;
    for (i = 0; i + 3 < n; i += 4) {
        s0 += a[i] - a[i];
        s1 += a[i + 1] - a[i + 1];
        s2 += a[i + 2] - a[i + 2];
        s3 += a[i + 3] - a[i + 3];
    }
    for (; i < n; i++) s0 += a[i] - a[i];
    return s0 == 0.0 && s1 == 0.0 && s2 == 0.0 && s3 == 0.0;
}

long fp_jacobian_work_size(const fp_plant *p)
{
    if (p == NULL) return 0;
    return 4L * p->nx;
}

/* The Schur complement of M at phi (c = cos phi) and eta (I3eta = I3.eta, ee = eta.eta): the 2x2
 * block [[a00, a01], [a01, a11]] and its inverse, as rhs_nonlinear forms it (the linear model:
 * c = 1, s = 0, eta = 0). */
typedef struct schur {
    double c, i00, i01, i11;   /* inverse of the 2x2 block */
} schur;

static void schur_at(const fp_plant *p, double c, double s, double I3eta, double ee, schur *S)
{
    const double a00 = p->I0 - c * c * p->I3I3;
    const double a01 = -p->I1 * c + s * I3eta + c * p->I3I5;
    const double a11 = p->I2 + ee - p->I5I5;
    const double det = a00 * a11 - a01 * a01;
    S->c = c;
    S->i00 = a11 / det;
    S->i01 = -a01 / det;
    S->i11 = a00 / det;
}

/* Solve M z = r in place: r = [r0, r1, re (n, at stride `stride`)] -> z. With
 * M = [[A, B], [B^T, I]], B^T = [-c I3, I5]: (A - B B^T) z_rig = r_rig - B re, z_e = re - B^T
 * z_rig. */
static void schur_solve(const fp_plant *p, const schur *S, double *r0, double *r1, double *re,
                        long stride)
{
    const int n = p->n;
    double I3re = 0.0, I5re = 0.0, q0, q1, z0, z1;
    int j;
    for (j = 0; j < n; j++) {
        I3re += p->I3[j] * re[j * stride];
        I5re += p->I5[j] * re[j * stride];
    }
    q0 = *r0 + S->c * I3re;
    q1 = *r1 - I5re;
    z0 = S->i00 * q0 + S->i01 * q1;
    z1 = S->i01 * q0 + S->i11 * q1;
    for (j = 0; j < n; j++) re[j * stride] += S->c * z0 * p->I3[j] - z1 * p->I5[j];
    *r0 = z0;
    *r1 = z1;
}

/* What the columns of the nonlinear model share at one state. */
typedef struct jac_point {
    double c, s, phid, I3eta, I3etad, ee, dm01, I3ae;
    const double *a;        /* qdd (nq) */
    const double *kge;      /* Kg eta (n), preload */
    const double *kgse;     /* (Kg + Kg^T)/2 eta (n), preload */
} jac_point;

static void jac_point_at(const fp_plant *p, const double *x, const double *dx, double *work,
                         jac_point *P)
{
    const int n = p->n, nq = n + 2;
    int j, k;
    P->phid = x[nq + 1];
    P->c = cos(x[1]);
    P->s = sin(x[1]);
    P->I3eta = P->I3etad = P->ee = P->I3ae = 0.0;
    P->a = dx + nq;
    for (j = 0; j < n; j++) {
        P->I3eta += p->I3[j] * x[2 + j];
        P->I3etad += p->I3[j] * x[nq + 2 + j];
        P->ee += x[2 + j] * x[2 + j];
        P->I3ae += p->I3[j] * P->a[2 + j];
    }
    P->dm01 = p->I1 * P->s + P->c * P->I3eta;
    P->kge = P->kgse = NULL;
    if (p->preload) {
        double *kge = work, *kgse = work + n;
        for (j = 0; j < n; j++) kge[j] = kgse[j] = 0.0;
        for (j = 0; j < n; j++)
            for (k = 0; k < n; k++) {
                const double g = p->Kg[(size_t)j * n + k];
                kge[j] += g * x[2 + k];
                kgse[j] += 0.5 * g * x[2 + k];
                kgse[k] += 0.5 * g * x[2 + j];
            }
        P->kge = kge;
        P->kgse = kgse;
    }
}

int fp_jacobian(const fp_plant *p, const double *x, double u, double *J, double *b, double *work)
{
    const int n = p->n, nq = n + 2, nx = p->nx;
    const double *I3 = p->I3;
    double *dx = work;            /* nx: dx/dt at x */
    schur S;
    int i, j, k;
    if (p->stiffened || x == NULL || J == NULL || work == NULL) return FP_BADARG;
    for (i = 0; i < nx * nx; i++) J[i] = 0.0;
    for (i = 0; i < nq; i++) J[(size_t)i * nx + nq + i] = 1.0;     /* d q/dt = qd */
    /* the rows of qdd: column k of J is written into J[nq.., k] at stride nx, then solved */
#define R(row, col) J[(size_t)(nq + (row)) * nx + (col)]
    if (p->linear) {
        schur_at(p, 1.0, 0.0, 0.0, 0.0, &S);
        /* -K0 and -D0 by columns (K0: [[0, 0, 0], [0, -g I1, -g I3], [0, -g I3, K - Kg]]) */
        R(1, 1) = p->g * p->I1;
        for (j = 0; j < n; j++) {
            R(2 + j, 1) = p->g * I3[j];
            R(1, 2 + j) = p->g * I3[j];
            R(2 + j, 2 + j) = -p->K[j];
            if (p->preload)
                for (i = 0; i < n; i++) R(2 + i, 2 + j) += p->Kg[(size_t)i * n + j];
            R(2 + j, nq + 2 + j) = -p->D[j];
        }
    } else {
        jac_point P;
        double phid, c, s, phid2;
        fp_rhs(p, x, u, dx);
        jac_point_at(p, x, dx, work + nx, &P);
        phid = P.phid;
        c = P.c;
        s = P.s;
        phid2 = phid * phid;
        schur_at(p, c, s, P.I3eta, P.ee, &S);
        {   /* column phi */
            const double a0 = P.a[0], a1 = P.a[1];
            double r0 = -(p->I1 * c - P.I3eta * s) * phid2 - 2.0 * phid * c * P.I3etad;
            double r1 = p->g * (p->I1 * c - P.I3eta * s);
            r0 -= P.dm01 * a1 + s * P.I3ae;
            r1 -= P.dm01 * a0;
            if (p->preload) {
                double ekge = 0.0;
                for (j = 0; j < n; j++) ekge += x[2 + j] * P.kge[j];
                r1 -= 0.5 * c * ekge;
            }
            R(0, 1) = r0;
            R(1, 1) = r1;
            for (j = 0; j < n; j++) {
                R(2 + j, 1) = p->g * c * I3[j] - s * I3[j] * a0;
                if (p->preload) R(2 + j, 1) -= s * P.kge[j];
            }
        }
        for (j = 0; j < n; j++) {   /* columns eta_j */
            const int col = 2 + j;
            R(0, col) = -c * phid2 * I3[j] - s * I3[j] * P.a[1];
            R(1, col) = -2.0 * phid * x[nq + 2 + j] + p->g * c * I3[j]
                        - (s * I3[j] * P.a[0] + 2.0 * x[2 + j] * P.a[1]);
            if (p->preload) {
                R(1, col) -= s * P.kgse[j];
                for (i = 0; i < n; i++) R(2 + i, col) = c * p->Kg[(size_t)i * n + j];
            }
            R(2 + j, col) += phid2 - p->K[j];
        }
        {   /* column phid */
            double eed = 0.0;
            for (j = 0; j < n; j++) eed += x[2 + j] * x[nq + 2 + j];
            R(0, nq + 1) = -2.0 * (p->I1 * s + P.I3eta * c) * phid - 2.0 * s * P.I3etad;
            R(1, nq + 1) = -2.0 * eed;
            for (j = 0; j < n; j++) R(2 + j, nq + 1) = 2.0 * phid * x[2 + j];
        }
        for (j = 0; j < n; j++) {   /* columns etad_j */
            const int col = nq + 2 + j;
            R(0, col) = -2.0 * phid * s * I3[j];
            R(1, col) = -2.0 * phid * x[2 + j];
            R(2 + j, col) = -p->D[j];
        }
    }
    /* solve M Z = R for all columns at once, row by row (contiguous: the Schur complement of
     * schur_solve with the dot products accumulated over the rows of R) */
    {
        double *q0 = work + nx + 2 * n, *q1 = q0 + nx, *r0 = &R(0, 0), *r1 = &R(1, 0);
        for (k = 0; k < nx; k++) {
            q0[k] = r0[k];
            q1[k] = r1[k];
        }
        for (j = 0; j < n; j++) {
            const double *re = &R(2 + j, 0), a3 = S.c * I3[j], a5 = p->I5[j];
            if (p->preload) {             /* the eta columns are dense (c Kg) */
                for (k = 0; k < nx; k++) {
                    q0[k] += a3 * re[k];
                    q1[k] -= a5 * re[k];
                }
            } else {                      /* row eta_j: columns phi, eta_j, phid, etad_j only */
                const int cols[4] = {1, 2 + j, nq + 1, nq + 2 + j};
                for (i = 0; i < 4; i++) {
                    q0[cols[i]] += a3 * re[cols[i]];
                    q1[cols[i]] -= a5 * re[cols[i]];
                }
            }
        }
        for (k = 0; k < nx; k++) {
            r0[k] = S.i00 * q0[k] + S.i01 * q1[k];
            r1[k] = S.i01 * q0[k] + S.i11 * q1[k];
        }
        for (j = 0; j < n; j++) {
            double *re = &R(2 + j, 0);
            const double a3 = S.c * I3[j], a5 = p->I5[j];
            for (k = 0; k < nx; k++) re[k] += a3 * r0[k] - a5 * r1[k];
        }
    }
#undef R
    if (b != NULL) {
        double r0 = 1.0, r1 = 0.0;
        for (i = 0; i < nx; i++) b[i] = 0.0;
        schur_solve(p, &S, &r0, &r1, b + nq + 2, 1);
        b[nq] = r0;
        b[nq + 1] = r1;
    }
    return all_finite_n(J, (long)nx * nx) && (b == NULL || all_finite_n(b, nx)) ? FP_OK
                                                                               : FP_NONFINITE;
}

/* out = J v + b du: the derivative of dx/dt along the direction v of the state and du of the
 * force, without forming J (O(n), O(n^2) with the preload). dx: dx/dt at (x, u); work: 2 n. */
static void jvp(const fp_plant *p, const double *x, const double *dx, const double *v,
                double du, double *out, double *work)
{
    const int n = p->n, nq = n + 2;
    const double *I3 = p->I3, *dq = v, *dv = v + nq;
    double r0, r1, *re = out + nq + 2, I3de = 0.0, I3dv = 0.0;
    schur S;
    int i, j;
    for (i = 0; i < nq; i++) out[i] = v[nq + i];
    for (j = 0; j < n; j++) {
        I3de += I3[j] * dq[2 + j];
        I3dv += I3[j] * dv[2 + j];
    }
    if (p->linear) {
        schur_at(p, 1.0, 0.0, 0.0, 0.0, &S);
        r0 = du;
        r1 = p->g * p->I1 * dq[1] + p->g * I3de;
        for (i = 0; i < n; i++) {
            re[i] = p->g * I3[i] * dq[1] - p->K[i] * dq[2 + i] - p->D[i] * dv[2 + i];
            if (p->preload)
                for (j = 0; j < n; j++) re[i] += p->Kg[(size_t)i * n + j] * dq[2 + j];
        }
    } else {
        jac_point P;
        double c, s, phid, phid2, a0, a1, eed = 0.0, edv = 0.0, rowsum = 0.0;
        jac_point_at(p, x, dx, work, &P);
        c = P.c;
        s = P.s;
        phid = P.phid;
        phid2 = phid * phid;
        a0 = P.a[0];
        a1 = P.a[1];
        schur_at(p, c, s, P.I3eta, P.ee, &S);
        for (j = 0; j < n; j++) {
            eed += x[2 + j] * x[nq + 2 + j];
            edv += x[2 + j] * dv[2 + j];
            /* row 1 of the eta columns times deta */
            rowsum += (-2.0 * phid * x[nq + 2 + j] + p->g * c * I3[j] - s * I3[j] * a0
                       - 2.0 * x[2 + j] * a1 - (p->preload ? s * P.kgse[j] : 0.0)) * dq[2 + j];
        }
        {   /* the phi column, times dphi */
            double rp0 = -(p->I1 * c - P.I3eta * s) * phid2 - 2.0 * phid * c * P.I3etad
                         - (P.dm01 * a1 + s * P.I3ae);
            double rp1 = p->g * (p->I1 * c - P.I3eta * s) - P.dm01 * a0;
            if (p->preload) {
                double ekge = 0.0;
                for (j = 0; j < n; j++) ekge += x[2 + j] * P.kge[j];
                rp1 -= 0.5 * c * ekge;
            }
            r0 = rp0 * dq[1] - (c * phid2 + s * a1) * I3de
                 + (-2.0 * (p->I1 * s + P.I3eta * c) * phid - 2.0 * s * P.I3etad) * dv[1]
                 - 2.0 * phid * s * I3dv + du;
            r1 = rp1 * dq[1] + rowsum - 2.0 * eed * dv[1] - 2.0 * phid * edv;
        }
        for (i = 0; i < n; i++) {
            double rp = p->g * c * I3[i] - s * I3[i] * a0;
            if (p->preload) {
                double kgd = 0.0;
                const double *row = p->Kg + (size_t)i * n;
                for (j = 0; j < n; j++) kgd += row[j] * dq[2 + j];
                rp -= s * P.kge[i];
                re[i] = c * kgd;
            } else {
                re[i] = 0.0;
            }
            re[i] += rp * dq[1] + (phid2 - p->K[i]) * dq[2 + i] + 2.0 * phid * x[2 + i] * dv[1]
                     - p->D[i] * dv[2 + i];
        }
    }
    schur_solve(p, &S, &r0, &r1, re, 1);
    out[nq] = r0;
    out[nq + 1] = r1;
}

int fp_jvp(const fp_plant *p, const double *x, double u, const double *v, double du, double *out,
           double *work)
{
    const int nx = p->nx;
    int i;
    if (p->stiffened || x == NULL || v == NULL || out == NULL || work == NULL) return FP_BADARG;
    fp_rhs(p, x, u, work);
    jvp(p, x, work, v, du, out, work + nx);
    for (i = 0; i < nx; i++)
        if (!isfinite(out[i])) return FP_NONFINITE;
    return FP_OK;
}

int fp_output_jacobian(const fp_plant *p, const double *x, double *C)
{
    const int n = p->n, nq = n + 2, nx = p->nx, ny = FP_OUT_ETA + n;
    const double *I3 = p->I3, *I5 = p->I5, *ts = p->tip_slope;
    const double phi = x[1], xd = x[nq], phid = x[nq + 1];
    double *dE;
    int i, j, k;
    if (p->stiffened) return FP_BADARG;
    for (i = 0; i < ny * nx; i++) C[i] = 0.0;
#define CC(row, col) C[(size_t)(row) * nx + (col)]
    CC(FP_OUT_X, 0) = 1.0;
    CC(FP_OUT_XDOT, nq) = 1.0;
    CC(FP_OUT_PHI_O, 1) = 1.0;
    CC(FP_OUT_OMEGA_O, nq + 1) = 1.0;
    CC(FP_OUT_PHI, 1) = 1.0;
    for (j = 0; j < n; j++) {
        CC(FP_OUT_TIP, 2 + j) = p->tip_defl[j];
        CC(FP_OUT_ETA + j, 2 + j) = 1.0;
    }
    if (p->linear) {
        for (j = 0; j < n; j++) {
            CC(FP_OUT_PHI_O, 2 + j) = ts[j];
            CC(FP_OUT_OMEGA_O, nq + 2 + j) = ts[j];
        }
    } else if (n > 0) {
        double sl = 0.0, sld = 0.0, w;
        for (j = 0; j < n; j++) {
            sl += ts[j] * x[2 + j];
            sld += ts[j] * x[nq + 2 + j];
        }
        w = 1.0 + sl * sl;
        for (j = 0; j < n; j++) {
            CC(FP_OUT_PHI_O, 2 + j) = ts[j] / w;
            CC(FP_OUT_OMEGA_O, nq + 2 + j) = ts[j] / w;
            CC(FP_OUT_OMEGA_O, 2 + j) = -2.0 * sl * sld / (w * w) * ts[j];
        }
    }
    /* the energy's gradient (dynamics.py, output_jacobian_numpy) */
    dE = C + (size_t)FP_OUT_ENERGY * nx;
    if (p->linear) {
        double I3e = 0.0, I3ed = 0.0, I5ed = 0.0;
        for (j = 0; j < n; j++) {
            I3e += I3[j] * x[2 + j];
            I3ed += I3[j] * x[nq + 2 + j];
            I5ed += I5[j] * x[nq + 2 + j];
        }
        /* [K0s q, M0 qd] */
        dE[1] = -p->g * p->I1 * phi - p->g * I3e;
        dE[nq] = p->I0 * xd - p->I1 * phid - I3ed;
        dE[nq + 1] = -p->I1 * xd + p->I2 * phid + I5ed;
        for (j = 0; j < n; j++) {
            dE[2 + j] = -p->g * I3[j] * phi + p->K[j] * x[2 + j];
            if (p->preload)
                for (k = 0; k < n; k++)
                    dE[2 + j] -= 0.5 * (p->Kg[(size_t)j * n + k] + p->Kg[(size_t)k * n + j])
                                 * x[2 + k];
            dE[nq + 2 + j] = -I3[j] * xd + I5[j] * phid + x[nq + 2 + j];
        }
    } else {
        const double c = cos(phi), s = sin(phi);
        double I3e = 0.0, I3ed = 0.0, I5ed = 0.0, ee = 0.0;
        for (j = 0; j < n; j++) {
            I3e += I3[j] * x[2 + j];
            I3ed += I3[j] * x[nq + 2 + j];
            I5ed += I5[j] * x[nq + 2 + j];
            ee += x[2 + j] * x[2 + j];
        }
        dE[1] = xd * ((p->I1 * phid + I3ed) * s + phid * c * I3e) - p->g * (p->I1 * s + c * I3e);
        dE[nq] = p->I0 * xd - (p->I1 * phid + I3ed) * c + phid * s * I3e;
        dE[nq + 1] = xd * (-p->I1 * c + s * I3e) + phid * (p->I2 + ee) + I5ed;
        for (j = 0; j < n; j++) {
            dE[2 + j] = xd * phid * s * I3[j] + phid * phid * x[2 + j] - p->g * s * I3[j]
                        + p->K[j] * x[2 + j];
            dE[nq + 2 + j] = -xd * c * I3[j] + phid * I5[j] + x[nq + 2 + j];
        }
        if (p->preload) {
            double ekge = 0.0;
            for (j = 0; j < n; j++)
                for (k = 0; k < n; k++) {
                    const double g = p->Kg[(size_t)j * n + k];
                    ekge += x[2 + j] * g * x[2 + k];
                    dE[2 + j] -= 0.5 * c * g * x[2 + k];
                    dE[2 + k] -= 0.5 * c * g * x[2 + j];
                }
            dE[1] += 0.5 * s * ekge;
        }
    }
#undef CC
    for (i = 0; i < ny * nx; i++)
        if (!isfinite(C[i])) return FP_NONFINITE;
    return FP_OK;
}

/* (etad.Kg.eta - eta.Kg.etad) / 2 for two vectors a (etad) and e (eta). */
static double kg_skew(const fp_plant *p, const double *a, const double *e)
{
    const int n = p->n;
    double acc = 0.0;
    int j, k;
    for (j = 0; j < n; j++)
        for (k = 0; k < n; k++) acc += p->Kg[(size_t)j * n + k] * (a[j] * e[k] - e[j] * a[k]);
    return 0.5 * acc;
}

int fp_output_derivatives(const fp_plant *p, const double *x, double u, double du, double *d1,
                          double *d2, double *work)
{
    const int n = p->n, nq = n + 2, nx = p->nx, ny = FP_OUT_ETA + n;
    const double *ts = p->tip_slope, *td = p->tip_defl;
    double *f = work, *g = work + nx;        /* f = dx/dt, g = d2x/dt2 = J f + b du */
    const double *qd, *a, *jj;
    double sl = 0.0, sld = 0.0, sldd = 0.0, slddd = 0.0, tip1 = 0.0, tip2 = 0.0;
    double P, dP, diss = 0.0, ddiss = 0.0;
    int i, j;
    if (p->stiffened || x == NULL || d1 == NULL || d2 == NULL || work == NULL) return FP_BADARG;
    fp_rhs(p, x, u, f);
    jvp(p, x, f, f, du, g, work + 2 * nx);
    qd = x + nq;
    a = f + nq;
    jj = g + nq;
    for (j = 0; j < n; j++) {
        sl += ts[j] * x[2 + j];
        sld += ts[j] * qd[2 + j];
        sldd += ts[j] * a[2 + j];
        slddd += ts[j] * jj[2 + j];
        tip1 += td[j] * qd[2 + j];
        tip2 += td[j] * a[2 + j];
        diss += p->D[j] * qd[2 + j] * qd[2 + j];
        ddiss += 2.0 * p->D[j] * qd[2 + j] * a[2 + j];
        d1[FP_OUT_ETA + j] = qd[2 + j];
        d2[FP_OUT_ETA + j] = a[2 + j];
    }
    d1[FP_OUT_X] = qd[0];
    d2[FP_OUT_X] = a[0];
    d1[FP_OUT_XDOT] = a[0];
    d2[FP_OUT_XDOT] = jj[0];
    d1[FP_OUT_PHI] = qd[1];
    d2[FP_OUT_PHI] = a[1];
    d1[FP_OUT_TIP] = tip1;
    d2[FP_OUT_TIP] = tip2;
    if (p->linear) {
        d1[FP_OUT_PHI_O] = qd[1] + sld;
        d1[FP_OUT_OMEGA_O] = d2[FP_OUT_PHI_O] = a[1] + sldd;
        d2[FP_OUT_OMEGA_O] = jj[1] + slddd;
    } else {
        /* phi_o = phi + atan(sl), omega_o = phid + sld / w, w = 1 + sl^2 */
        const double w = 1.0 + sl * sl, w2 = w * w, sld2 = sld * sld;
        d1[FP_OUT_PHI_O] = qd[1] + sld / w;
        d1[FP_OUT_OMEGA_O] = d2[FP_OUT_PHI_O] = a[1] + sldd / w - 2.0 * sl * sld2 / w2;
        d2[FP_OUT_OMEGA_O] = jj[1] + slddd / w - 6.0 * sl * sld * sldd / w2 - 2.0 * sld2 * sld / w2
                             + 8.0 * sl * sl * sld2 * sld / (w2 * w);
    }
    /* the energy: the power balance dE/dt = F_c xd - etad.D.etad (+ the power of the skew part of
     * Kg, c (etad.Kg.eta - eta.Kg.etad) / 2, zero for a symmetric Kg): exact, since the equations
     * are Lagrange's for the kinetic and potential energies fp_energy sums (docs/model.md,
     * section 4; tests/plant/test_lagrange.py) with the Rayleigh damping and the force on the cart. */
    P = u * qd[0] - diss;
    dP = du * qd[0] + u * a[0] - ddiss;
    if (p->preload) {
        const double k1 = kg_skew(p, qd + 2, x + 2), k2 = kg_skew(p, a + 2, x + 2);
        if (p->linear) {
            P += k1;
            dP += k2;
        } else {
            const double c = cos(x[1]), s = sin(x[1]);
            P += c * k1;
            dP += c * k2 - s * qd[1] * k1;
        }
    }
    d1[FP_OUT_ENERGY] = P;
    d2[FP_OUT_ENERGY] = dP;
    for (i = 0; i < ny; i++)
        if (!isfinite(d1[i]) || !isfinite(d2[i])) return FP_NONFINITE;
    return FP_OK;
}

/* ==== The exact rung: ANCF cable elements on the cart (plant_fmu/exact.py) ==================== */

#define EX_KL 7                          /* half-bandwidth of the element coupling */
#define EX_KU 7
#define EX_W (2 * EX_KL + EX_KU + 1)     /* band storage per column, room for the pivots' fill */
#define EX_NG 5

int fp_exact_prepare(fp_exact *p)
{
    double r, x[EX_NG], w[EX_NG], s70 = sqrt(70.0), a, b;
    int g;
    if (p == NULL || p->ne < 1 || p->ne > 100000 || p->max_iter < 1) return FP_BADARG;
    if (!(isfinite(p->L) && p->L > 0 && isfinite(p->EA) && p->EA > 0 && isfinite(p->EI)
          && p->EI > 0 && isfinite(p->rhoA) && p->rhoA > 0 && isfinite(p->g)
          && isfinite(p->m) && p->m > 0 && isfinite(p->beta_kv) && p->beta_kv >= 0
          && isfinite(p->h) && p->h > 0 && p->rho_inf >= 0 && p->rho_inf <= 1
          && isfinite(p->tol) && p->tol > 0))
        return FP_BADARG;
    p->nq = 4 * p->ne + 3;
    p->le = p->L / p->ne;
    r = p->rho_inf;
    p->am = (2 * r - 1) / (r + 1);
    p->af = r / (r + 1);
    p->gamma = 0.5 + p->af - p->am;
    p->beta = 0.25 * (p->gamma + 0.5) * (p->gamma + 0.5);
    p->bp = (1 - p->af) / (1 - p->am);
    /* 5-point Gauss-Legendre on [-1, 1], in closed form */
    a = sqrt(5.0 - 2.0 * sqrt(10.0 / 7.0)) / 3.0;
    b = sqrt(5.0 + 2.0 * sqrt(10.0 / 7.0)) / 3.0;
    x[0] = -b; x[1] = -a; x[2] = 0.0; x[3] = a; x[4] = b;
    w[0] = w[4] = (322.0 - 13.0 * s70) / 900.0;
    w[1] = w[3] = (322.0 + 13.0 * s70) / 900.0;
    w[2] = 128.0 / 225.0;
    for (g = 0; g < EX_NG; g++) {
        double xi = 0.5 * (x[g] + 1.0), le = p->le, *d1 = p->gd1 + 4 * g, *d2 = p->gd2 + 4 * g;
        p->gw[g] = 0.5 * w[g] * le;
        d1[0] = (-6 * xi + 6 * xi * xi) / le;
        d1[1] = 1 - 4 * xi + 3 * xi * xi;
        d1[2] = (6 * xi - 6 * xi * xi) / le;
        d1[3] = -2 * xi + 3 * xi * xi;
        d2[0] = (-6 + 12 * xi) / (le * le);
        d2[1] = (-4 + 6 * xi) / le;
        d2[2] = (6 - 12 * xi) / (le * le);
        d2[3] = (-2 + 6 * xi) / le;
    }
    return FP_OK;
}

/* work: band (EX_W nq), pivots (nq), Sherman-Morrison y and w (2 nq), 12 vectors of nq, the
 * nodal vectors e and ed (2 (nq + 1)). */
long fp_exact_work_size(const fp_exact *p)
{
    /* the layouts end with e and ed; after them the modal law's d_t and C_f d_t (2 nq) */
    return p == NULL ? 0 : (long)p->nq * (EX_W + 17) + 2 * ((long)p->nq + 1) + 8;
}

/* The q index of the full nodal index k (-1: the root's y, held at 0). */
static int ex_qi(int k) { return k == 0 ? 0 : (k == 1 ? -1 : k - 1); }

/* The element's internal force fe (8) and, if ke is not NULL, its tangents ke = dfe/de and
 * ce = dfe/ded (8 x 8), from its nodal values ee, eed (exact.py, CableMesh.internal). */
static void ex_element(const fp_exact *p, const double *ee, const double *eed, double *fe,
                       double *ke, double *ce)
{
    const double EA = p->EA, EI = p->EI, beta = p->beta_kv;
    const int damp = beta > 0.0;
    int g, i, j, k;
    for (i = 0; i < 8; i++) fe[i] = 0.0;
    if (ke != NULL)
        for (i = 0; i < 64; i++) ke[i] = ce[i] = 0.0;
    for (g = 0; g < EX_NG; g++) {
        const double *d1 = p->gd1 + 4 * g, *d2 = p->gd2 + 4 * g, wg = p->gw[g];
        double ab[4] = {0, 0, 0, 0}, abd[4] = {0, 0, 0, 0}, de[4], dk[4], He[16], Hk[16], H[16],
               Cg[16], grad[4], n, la, c, eps, kap, sig, mom, Rb[2], RTa[2], n2, n3;
        for (k = 0; k < 4; k++) {
            ab[0] += d1[k] * ee[2 * k];
            ab[1] += d1[k] * ee[2 * k + 1];
            ab[2] += d2[k] * ee[2 * k];
            ab[3] += d2[k] * ee[2 * k + 1];
            abd[0] += d1[k] * eed[2 * k];
            abd[1] += d1[k] * eed[2 * k + 1];
            abd[2] += d2[k] * eed[2 * k];
            abd[3] += d2[k] * eed[2 * k + 1];
        }
        n = ab[0] * ab[0] + ab[1] * ab[1];
        if (!(n > 0.0)) n = NAN;       /* a tangent of zero length: no strain (NaN, no 1/0) */
        la = sqrt(n);
        c = ab[0] * ab[3] - ab[1] * ab[2];
        eps = la - 1.0;
        kap = c / n;
        Rb[0] = ab[3]; Rb[1] = -ab[2];            /* R b, R = [[0, 1], [-1, 0]] */
        RTa[0] = -ab[1]; RTa[1] = ab[0];          /* R^T a */
        de[0] = ab[0] / la; de[1] = ab[1] / la; de[2] = de[3] = 0.0;
        dk[0] = Rb[0] / n - 2.0 * (c / (n * n)) * ab[0];
        dk[1] = Rb[1] / n - 2.0 * (c / (n * n)) * ab[1];
        dk[2] = RTa[0] / n;
        dk[3] = RTa[1] / n;
        sig = EA * eps;
        mom = EI * kap;
        if (damp) {
            double epsd = 0, kapd = 0;
            for (i = 0; i < 4; i++) {
                epsd += de[i] * abd[i];
                kapd += dk[i] * abd[i];
            }
            sig = sig + beta * EA * epsd;
            mom = mom + beta * EI * kapd;
        }
        for (i = 0; i < 4; i++) grad[i] = (sig * de[i] + mom * dk[i]) * wg;
        for (k = 0; k < 4; k++) {
            fe[2 * k] += d1[k] * grad[0] + d2[k] * grad[2];
            fe[2 * k + 1] += d1[k] * grad[1] + d2[k] * grad[3];
        }
        if (ke == NULL) continue;
        for (i = 0; i < 16; i++) He[i] = Hk[i] = 0.0;
        n2 = n * n;
        n3 = n2 * n;
        for (i = 0; i < 2; i++)
            for (j = 0; j < 2; j++) {
                double aa = ab[i] * ab[j], I = i == j ? 1.0 : 0.0;
                He[4 * i + j] = I / la - aa / (la * la * la);
                Hk[4 * i + j] = -2.0 * (Rb[i] * ab[j] + ab[i] * Rb[j]) / n2 - 2.0 * c * I / n2
                                + 8.0 * c * aa / n3;
            }
        /* Hab = R / n - 2 (a a^T R) / n^2, (a a^T R)_ij = a_i (a^T R)_j, a^T R = (-a1, a0) */
        for (i = 0; i < 2; i++)
            for (j = 0; j < 2; j++) {
                double Rij = (i == 0 && j == 1) ? 1.0 : ((i == 1 && j == 0) ? -1.0 : 0.0);
                double v = Rij / n - 2.0 * (ab[i] * RTa[j]) / n2;
                Hk[4 * i + 2 + j] = v;
                Hk[4 * (2 + j) + i] = v;
            }
        for (i = 0; i < 4; i++)
            for (j = 0; j < 4; j++) {
                H[4 * i + j] = EA * de[i] * de[j] + EI * dk[i] * dk[j];
                Cg[4 * i + j] = damp ? beta * H[4 * i + j] : 0.0;
            }
        for (i = 0; i < 16; i++) H[i] = H[i] + sig * He[i] + mom * Hk[i];
        if (damp) {
            double Hea[4], Hka[4];
            for (i = 0; i < 4; i++) {
                Hea[i] = Hka[i] = 0.0;
                for (j = 0; j < 4; j++) {
                    Hea[i] += He[4 * i + j] * abd[j];
                    Hka[i] += Hk[4 * i + j] * abd[j];
                }
            }
            for (i = 0; i < 4; i++)
                for (j = 0; j < 4; j++)
                    H[4 * i + j] += beta * (EA * de[i] * Hea[j] + EI * dk[i] * Hka[j]);
        }
        /* ke += G^T (H wg) G: G (4 x 8) maps the dof 2k + c (c = 0: x, 1: y) to the rows c
         * (with d1[k]) and c + 2 (with d2[k]) alone, so each entry sums four terms */
        for (i = 0; i < 8; i++) {
            const int ki = i >> 1, ci = i & 1;
            const double gi0 = d1[ki], gi1 = d2[ki];
            for (j = 0; j < 8; j++) {
                const int kj = j >> 1, cj = j & 1;
                const double gj0 = d1[kj], gj1 = d2[kj];
                const int r0 = ci, r1 = ci + 2, s0 = cj, s1 = cj + 2;
                ke[8 * i + j] += (gi0 * (H[4 * r0 + s0] * gj0 + H[4 * r0 + s1] * gj1)
                                  + gi1 * (H[4 * r1 + s0] * gj0 + H[4 * r1 + s1] * gj1)) * wg;
                if (damp)
                    ce[8 * i + j] += (gi0 * (Cg[4 * r0 + s0] * gj0 + Cg[4 * r0 + s1] * gj1)
                                      + gi1 * (Cg[4 * r1 + s0] * gj0 + Cg[4 * r1 + s1] * gj1))
                                     * wg;
            }
        }
    }
}

/* The element's consistent mass, kron(me, I2) (beam.py, _element_matrices). */
static double ex_mass(const fp_exact *p, int i, int j)
{
    const double le = p->le, l2 = le * le;
    const double me[16] = {156, 22 * le, 54, -13 * le, 22 * le, 4 * l2, 13 * le, -3 * l2,
                           54, 13 * le, 156, -22 * le, -13 * le, -3 * l2, -22 * le, 4 * l2};
    if ((i & 1) != (j & 1)) return 0.0;
    return p->rhoA * le / 420 * me[4 * (i >> 1) + (j >> 1)];
}

#define AB(i, j) band[(long)(j) * EX_W + (EX_KL + EX_KU + (i) - (j))]

/* The forces f (nq) of M qdd = f at q, qd with the force u, and what the caller asks of the
 * tangent: (K, C, M) dense (any may be NULL), or, with band != NULL, the band of
 * cm M + ck K + cc C. e, ed: nq + 1 doubles each. FP_OK or FP_NONFINITE. */
/* A band that ex_forces assembles: cm M + ck K + cc C, every stride-th double of band (stride 2:
 * the real or imaginary parts of a complex band). */
typedef struct ex_target {
    double *band;
    double cm, ck, cc;
    int stride;
} ex_target;

#define ABS_(b, st, i, j) (b)[(long)(st) * ((long)(j) * EX_W + (EX_KL + EX_KU + (i) - (j)))]

static int ex_forces_to(const fp_exact *p, const double *q, const double *qd, double u,
                        double *f, double *K, double *C, double *M, const ex_target *tg, int ntg,
                        double *e, double *ed);
static void ex_modal_force(const fp_exact *p, const double *e, const double *ed, double *f,
                           double *scratch);

static int ex_forces(const fp_exact *p, const double *q, const double *qd, double u, double *f,
                     double *K, double *C, double *M, double *band, double cm, double ck,
                     double cc, double *e, double *ed)
{
    ex_target t;
    t.band = band;
    t.cm = cm;
    t.ck = ck;
    t.cc = cc;
    t.stride = 1;
    return ex_forces_to(p, q, qd, u, f, K, C, M, band != NULL ? &t : NULL, band != NULL ? 1 : 0,
                        e, ed);
}

/* ex_forces into the bands of ntg targets. */
static int ex_forces_to(const fp_exact *p, const double *q, const double *qd, double u,
                        double *f, double *K, double *C, double *M, const ex_target *tg, int ntg,
                        double *e, double *ed)
{
    const int nq = p->nq, nd = nq + 1;
    const double le = p->le, int_h[4] = {le * 0.5, le * (le / 12), le * 0.5, le * (-le / 12)};
    const int tangent = K != NULL || C != NULL || ntg > 0;
    int el, i, j, k, t;
    double fe[8], ke[64], ce[64];
    e[0] = q[0]; e[1] = 0.0;
    ed[0] = qd[0]; ed[1] = 0.0;
    for (k = 2; k < nd; k++) {
        e[k] = q[k - 1];
        ed[k] = qd[k - 1];
    }
    for (i = 0; i < nq; i++) f[i] = 0.0;
    if (K != NULL)
        for (i = 0; i < nq * nq; i++) K[i] = 0.0;
    if (C != NULL)
        for (i = 0; i < nq * nq; i++) C[i] = 0.0;
    if (M != NULL) {
        for (i = 0; i < nq * nq; i++) M[i] = 0.0;
        M[0] = p->m;
    }
    for (t = 0; t < ntg; t++) {
        for (i = 0; i < nq * EX_W; i++) tg[t].band[(long)tg[t].stride * i] = 0.0;
        ABS_(tg[t].band, tg[t].stride, 0, 0) = tg[t].cm * p->m;
    }
    for (el = 0; el < p->ne; el++) {
        const int b0 = 4 * el;
        ex_element(p, e + b0, ed + b0, fe, tangent ? ke : NULL, ce);
        for (i = 0; i < 8; i++) {
            int qi = ex_qi(b0 + i);
            if (qi < 0) continue;
            f[qi] -= fe[i];
            if (i & 1) f[qi] -= p->g * p->rhoA * int_h[i >> 1];
            for (j = 0; j < 8; j++) {
                int qj = ex_qi(b0 + j);
                if (qj < 0) continue;
                if (K != NULL) K[(long)qi * nq + qj] += ke[8 * i + j];
                if (C != NULL) C[(long)qi * nq + qj] += ce[8 * i + j];
                if (M != NULL) M[(long)qi * nq + qj] += ex_mass(p, i, j);
                for (t = 0; t < ntg; t++)
                    ABS_(tg[t].band, tg[t].stride, qi, qj) += tg[t].cm * ex_mass(p, i, j)
                                                              + tg[t].ck * ke[8 * i + j]
                                                              + tg[t].cc * ce[8 * i + j];
            }
        }
    }
    if (p->modal != NULL) ex_modal_force(p, e, ed, f, ed + nd);
    f[0] += u;
    return finite_array(f, nq) ? FP_OK : FP_NONFINITE;
}

/* ================================================ the modal law (plant_fmu/exact.py: FrameModalDamping)
 * d: [d0 = |r'_0| - 1, then per node i = 1..ne: u, w, u', w'] in the root tangent's frame. */

/* The frame at the nodal vector e: b1 (along the root tangent), b2 = (-b1y, b1x) and the
 * gradient of its angle with respect to the root slope, g = (-a0y, a0x) / |a0|^2. */
static void ex_frame(const double *e, double *b1, double *b2, double *g)
{
    const double ax = e[2], ay = e[3], n0 = ax * ax + ay * ay, r = sqrt(n0);
    b1[0] = ax / r;
    b1[1] = ay / r;
    b2[0] = -b1[1];
    b2[1] = b1[0];
    g[0] = -ay / n0;
    g[1] = ax / n0;
}

/* f (the free coordinates) += -G^T C_f G ed at e; scratch: 2 nd doubles. */
static void ex_modal_force(const fp_exact *p, const double *e, const double *ed, double *f,
                           double *scratch)
{
    const int ne = p->ne, nd = 4 * ne + 1, na = 2 * ne + 1, nb = 2 * ne;
    const double *Ca = p->modal, *Cb = p->modal + (long)na * na;
    double b1[2], b2[2], g[2], th, coef = 0.0, *d = scratch, *c = scratch + nd, ga[2] = {0, 0};
    double gr0[2] = {0, 0};
    int i, j, k;
    ex_frame(e, b1, b2, g);
    th = g[0] * ed[2] + g[1] * ed[3];
    d[0] = b1[0] * ed[2] + b1[1] * ed[3];
    for (i = 1; i <= ne; i++) {
        const double rx = e[4 * i] - e[0], ry = e[4 * i + 1] - e[1];
        const double vx = ed[4 * i] - ed[0], vy = ed[4 * i + 1] - ed[1];
        const double *rp = e + 4 * i + 2, *vp = ed + 4 * i + 2;
        k = 1 + 4 * (i - 1);
        d[k] = th * (b2[0] * rx + b2[1] * ry) + b1[0] * vx + b1[1] * vy;
        d[k + 1] = -th * (b1[0] * rx + b1[1] * ry) + b2[0] * vx + b2[1] * vy;
        d[k + 2] = th * (b2[0] * rp[0] + b2[1] * rp[1]) + b1[0] * vp[0] + b1[1] * vp[1];
        d[k + 3] = -th * (b1[0] * rp[0] + b1[1] * rp[1]) + b2[0] * vp[0] + b2[1] * vp[1];
    }
    /* c = C_f d, block by block: axial (d0, u_i, u'_i) and bending (w_i, w'_i) */
    for (i = 0; i < na; i++) {
        const int di = i == 0 ? 0 : 1 + 4 * ((i - 1) / 2) + 2 * ((i - 1) % 2);
        double v = 0.0;
        for (j = 0; j < na; j++) {
            const int dj = j == 0 ? 0 : 1 + 4 * ((j - 1) / 2) + 2 * ((j - 1) % 2);
            v += Ca[(long)i * na + j] * d[dj];
        }
        c[di] = v;
    }
    for (i = 0; i < nb; i++) {
        const int di = 2 + 4 * (i / 2) + 2 * (i % 2);
        double v = 0.0;
        for (j = 0; j < nb; j++) v += Cb[(long)i * nb + j] * d[2 + 4 * (j / 2) + 2 * (j % 2)];
        c[di] = v;
    }
    /* f -= G^T c, onto the free coordinates (q[0] = e[0], q[k - 1] = e[k] for k >= 2) */
    ga[0] = c[0] * b1[0];
    ga[1] = c[0] * b1[1];
    for (i = 1; i <= ne; i++) {
        const double rx = e[4 * i] - e[0], ry = e[4 * i + 1] - e[1];
        const double *rp = e + 4 * i + 2;
        double px, py;
        k = 1 + 4 * (i - 1);
        coef += c[k] * (b2[0] * rx + b2[1] * ry) - c[k + 1] * (b1[0] * rx + b1[1] * ry)
                + c[k + 2] * (b2[0] * rp[0] + b2[1] * rp[1])
                - c[k + 3] * (b1[0] * rp[0] + b1[1] * rp[1]);
        px = c[k] * b1[0] + c[k + 1] * b2[0];
        py = c[k] * b1[1] + c[k + 1] * b2[1];
        f[4 * i - 1] -= px;                       /* e[4 i], e[4 i + 1] */
        f[4 * i] -= py;
        gr0[0] += px;
        gr0[1] += py;
        f[4 * i + 1] -= c[k + 2] * b1[0] + c[k + 3] * b2[0];   /* e[4 i + 2], e[4 i + 3] */
        f[4 * i + 2] -= c[k + 2] * b1[1] + c[k + 3] * b2[1];
    }
    ga[0] += coef * g[0];
    ga[1] += coef * g[1];
    f[0] += gr0[0];                               /* the root's x (its y is held) */
    f[1] -= ga[0];                                /* the root slope, e[2], e[3] */
    f[2] -= ga[1];
}

long fp_exact_modal_size(const fp_exact *p)
{
    long na, nb;
    if (p == NULL) return 0;
    na = 2L * p->ne + 1;
    nb = 2L * p->ne;
    return na * na + nb * nb;
}

long fp_exact_modal_work_size(const fp_exact *p)
{
    long na = p == NULL ? 0 : 2L * p->ne + 1;
    return 2 * na * na + 2 * na + 64;
}

/* The d index (block order) of the element dof 2 k + c of element el, and its sign; -1 when
 * the coordinate is clamped in the frame. block: 0 axial, 1 bending. */
static int ex_modal_index(int el, int k, int c, int *block, double *sign)
{
    const int j = 4 * el + 2 * k + c, node = j / 4, r = j % 4;      /* e index, its node */
    if (node == 0) {
        if (r != 3) return -1;                    /* the root's position and slope direction */
        *block = 0;
        *sign = 1.0;
        return 0;                                  /* d0: the root slope's stretch */
    }
    switch (r) {
    case 0: *block = 1; *sign = -1.0; return 2 * (node - 1);         /* w = -r_x */
    case 1: *block = 0; *sign = 1.0; return 1 + 2 * (node - 1);      /* u = r_y - s */
    case 2: *block = 1; *sign = -1.0; return 2 * (node - 1) + 1;     /* w' = -r'_x */
    default: *block = 0; *sign = 1.0; return 2 + 2 * (node - 1);     /* u' = r'_y - 1 */
    }
}

/* The eigen-decomposition of the symmetric a (n x n, row-major): on return a's columns are the
 * orthonormal eigenvectors and d the eigenvalues; e: n of scratch. Householder's reduction to
 * tridiagonal form with the transformation accumulated, then the QL iteration with implicit
 * shifts (Wilkinson & Reinsch's tred2 and tql2). 0 if the iteration does not converge. */
static int ex_symmetric_eigen(int n, double *a, double *d, double *e)
{
    int i, j, k, l, m, iter;
#define A_(r, c) a[(long)(r) * n + (c)]
    for (i = n - 1; i > 0; i--) {
        double h = 0.0, scale = 0.0;
        l = i - 1;
        if (l > 0) {
            for (k = 0; k <= l; k++) scale += fabs(A_(i, k));
            if (scale == 0.0) {
                e[i] = A_(i, l);
            } else {
                double f, g, hh;
                for (k = 0; k <= l; k++) {
                    A_(i, k) /= scale;
                    h += A_(i, k) * A_(i, k);
                }
                f = A_(i, l);
                g = f >= 0.0 ? -sqrt(h) : sqrt(h);
                e[i] = scale * g;
                h -= f * g;
                A_(i, l) = f - g;
                f = 0.0;
                for (j = 0; j <= l; j++) {
                    A_(j, i) = A_(i, j) / h;
                    g = 0.0;
                    for (k = 0; k <= j; k++) g += A_(j, k) * A_(i, k);
                    for (k = j + 1; k <= l; k++) g += A_(k, j) * A_(i, k);
                    e[j] = g / h;
                    f += e[j] * A_(i, j);
                }
                hh = f / (h + h);
                for (j = 0; j <= l; j++) {
                    f = A_(i, j);
                    e[j] = g = e[j] - hh * f;
                    for (k = 0; k <= j; k++) A_(j, k) -= f * e[k] + g * A_(i, k);
                }
            }
        } else {
            e[i] = A_(i, l);
        }
        d[i] = h;
    }
    d[0] = 0.0;
    e[0] = 0.0;
    for (i = 0; i < n; i++) {                      /* accumulate the transformations */
        l = i - 1;
        if (d[i] != 0.0)
            for (j = 0; j <= l; j++) {
                double g = 0.0;
                for (k = 0; k <= l; k++) g += A_(i, k) * A_(k, j);
                for (k = 0; k <= l; k++) A_(k, j) -= g * A_(k, i);
            }
        d[i] = A_(i, i);
        A_(i, i) = 1.0;
        for (j = 0; j <= l; j++) A_(j, i) = A_(i, j) = 0.0;
    }
    for (i = 1; i < n; i++) e[i - 1] = e[i];       /* the QL iteration */
    e[n - 1] = 0.0;
    for (l = 0; l < n; l++) {
        iter = 0;
        do {
            for (m = l; m < n - 1; m++) {
                const double dd = fabs(d[m]) + fabs(d[m + 1]);
                if (fabs(e[m]) <= 2.220446049250313e-16 * dd) break;
            }
            if (m != l) {
                double g, r, s, c, p, f, b;
                if (iter++ == 60) return 0;
                g = (d[l + 1] - d[l]) / (2.0 * e[l]);
                r = hypot(g, 1.0);
                g = d[m] - d[l] + e[l] / (g + copysign(r, g));
                s = c = 1.0;
                p = 0.0;
                for (i = m - 1; i >= l; i--) {
                    f = s * e[i];
                    b = c * e[i];
                    e[i + 1] = r = hypot(f, g);
                    if (r == 0.0) {
                        d[i + 1] -= p;
                        e[m] = 0.0;
                        break;
                    }
                    s = f / r;
                    c = g / r;
                    g = d[i + 1] - p;
                    r = (d[i] - g) * s + 2.0 * c * b;
                    d[i + 1] = g + (p = s * r);
                    g = c * r - b;
                    for (k = 0; k < n; k++) {
                        f = A_(k, i + 1);
                        A_(k, i + 1) = s * A_(k, i) + c * f;
                        A_(k, i) = c * A_(k, i) - s * f;
                    }
                }
                if (r == 0.0 && i >= l) continue;
                d[l] -= p;
                e[l] = g;
                e[m] = 0.0;
            }
        } while (m != l);
    }
    for (i = 0; i < n; i++)
        if (!isfinite(d[i])) return 0;
#undef A_
    return 1;
}

/* The generalized symmetric eigenproblem (K, M) of size n (row-major, overwritten): C =
 * (L V) diag(2 zeta sqrt(lambda)) (L V)^T into C (n x n), M = L L^T. work: 2 n (lambda). */
static int ex_modal_block(int n, double *M, double *K, double *C, double zeta, double *lam)
{
    int i, j, k, bw = 0;
    double *V = C;
    /* M's half-bandwidth (an element couples its two nodes): L keeps it, and the loops over L
     * skip the zeros outside it (the same sums: they only left out terms 0 * x) */
    for (i = 0; i < n; i++)
        for (j = 0; j < i; j++)
            if (M[(long)i * n + j] != 0.0 && i - j > bw) bw = i - j;
#define LO(i) ((i) - bw > 0 ? (i) - bw : 0)
    /* Cholesky in place (lower) */
    for (j = 0; j < n; j++) {
        double s = M[(long)j * n + j];
        for (k = LO(j); k < j; k++) s -= M[(long)j * n + k] * M[(long)j * n + k];
        if (!(s > 0.0) || !isfinite(s)) return FP_NOCONVERGE;
        M[(long)j * n + j] = sqrt(s);
        for (i = j + 1; i < n; i++) {
            double t = M[(long)i * n + j];
            if (i - j > bw) {
                M[(long)i * n + j] = 0.0;
                continue;
            }
            for (k = LO(i); k < j; k++) t -= M[(long)i * n + k] * M[(long)j * n + k];
            M[(long)i * n + j] = t / M[(long)j * n + j];
        }
    }
    /* K <- L^-1 K (columns), then K <- K L^-T (rows): the symmetric A */
    for (j = 0; j < n; j++)
        for (i = 0; i < n; i++) {
            double t = K[(long)i * n + j];
            for (k = LO(i); k < i; k++) t -= M[(long)i * n + k] * K[(long)k * n + j];
            K[(long)i * n + j] = t / M[(long)i * n + i];
        }
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            double t = K[(long)i * n + j];
            for (k = LO(j); k < j; k++) t -= K[(long)i * n + k] * M[(long)j * n + k];
            K[(long)i * n + j] = t / M[(long)j * n + j];
        }
    for (i = 0; i < n; i++)                       /* symmetric to round-off: make it exact */
        for (j = 0; j < i; j++) {
            double a = 0.5 * (K[(long)i * n + j] + K[(long)j * n + i]);
            K[(long)i * n + j] = K[(long)j * n + i] = a;
        }
    /* the eigenvectors V (columns) and eigenvalues of A (in K): Householder's reduction to
     * tridiagonal form, then the implicit QL iteration (O(n^3) with a small constant: at 100
     * elements several times faster than cyclic Jacobi) */
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) V[(long)i * n + j] = K[(long)i * n + j];
    if (!ex_symmetric_eigen(n, V, lam, lam + n)) return FP_NOCONVERGE;
    for (i = 0; i < n; i++) {
        double l = lam[i];
        lam[i] = 2.0 * zeta * sqrt(l > 0.0 ? l : 0.0);
    }
    /* W = L V into K, row by row */
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            double t = 0.0;
            for (k = LO(i); k <= i; k++) t += M[(long)i * n + k] * V[(long)k * n + j];
            K[(long)i * n + j] = t;
        }
    /* C = W diag W^T */
    for (i = 0; i < n; i++)
        for (j = 0; j <= i; j++) {
            double t = 0.0;
            for (k = 0; k < n; k++) t += K[(long)i * n + k] * lam[k] * K[(long)j * n + k];
            C[(long)i * n + j] = C[(long)j * n + i] = t;
        }
#undef LO
    return FP_OK;
}

int fp_exact_modal(const fp_exact *p, double zeta, double *C, double *work)
{
    const int ne = p == NULL ? 0 : p->ne, na = 2 * ne + 1, nb = 2 * ne;
    double *M, *K, *lam, fe[8], ke[64], ce[64], ee[8], eed[8];
    fp_exact flat;
    int el, blk, rc, k, c, k2, c2;
    if (p == NULL || C == NULL || work == NULL || !(zeta >= 0.0) || !isfinite(zeta))
        return FP_BADARG;
    flat = *p;
    flat.beta_kv = 0.0;
    flat.modal = NULL;
    M = work;
    K = M + (long)na * na;
    lam = K + (long)na * na;
    for (blk = 0; blk < 2; blk++) {
        const int n = blk == 0 ? na : nb;
        double *out = blk == 0 ? C : C + (long)na * na;
        int i;
        for (i = 0; i < n * n; i++) M[i] = K[i] = 0.0;
        for (el = 0; el < ne; el++) {
            /* the straight vertical beam: r = (0, s), r' = (0, 1) */
            const double s0 = p->le * el, s1 = p->le * (el + 1);
            ee[0] = 0.0; ee[1] = s0; ee[2] = 0.0; ee[3] = 1.0;
            ee[4] = 0.0; ee[5] = s1; ee[6] = 0.0; ee[7] = 1.0;
            for (i = 0; i < 8; i++) eed[i] = 0.0;
            ex_element(&flat, ee, eed, fe, ke, ce);
            for (k = 0; k < 4; k++)
                for (c = 0; c < 2; c++) {
                    int bi, bj;
                    double si, sj;
                    const int di = ex_modal_index(el, k, c, &bi, &si);
                    if (di < 0 || bi != blk) continue;
                    for (k2 = 0; k2 < 4; k2++)
                        for (c2 = 0; c2 < 2; c2++) {
                            const int dj = ex_modal_index(el, k2, c2, &bj, &sj);
                            if (dj < 0 || bj != blk) continue;
                            M[(long)di * n + dj] += si * sj * ex_mass(p, 2 * k + c, 2 * k2 + c2);
                            K[(long)di * n + dj] += si * sj * ke[8 * (2 * k + c) + 2 * k2 + c2];
                        }
                }
        }
        rc = ex_modal_block(n, M, K, out, zeta, lam);
        if (rc != FP_OK) return rc;
    }
    return FP_OK;
}

/* M v (nq) by elements. */
static void ex_mass_times(const fp_exact *p, const double *v, double *out)
{
    int el, i, j, nq = p->nq;
    for (i = 0; i < nq; i++) out[i] = 0.0;
    out[0] = p->m * v[0];
    for (el = 0; el < p->ne; el++)
        for (i = 0; i < 8; i++) {
            int qi = ex_qi(4 * el + i);
            if (qi < 0) continue;
            for (j = 0; j < 8; j++) {
                int qj = ex_qi(4 * el + j);
                if (qj >= 0) out[qi] += ex_mass(p, i, j) * v[qj];
            }
        }
}

/* Band LU with partial pivoting in place (LAPACK's dgbtrf layout); piv as doubles. FP_OK or
 * FP_NOCONVERGE (a zero pivot). */
static int ex_band_lu(int n, double *band, double *piv)
{
    int k, i, j;
    for (k = 0; k < n; k++) {
        int imax = k + EX_KL < n - 1 ? k + EX_KL : n - 1;
        int jmax = k + EX_KL + EX_KU < n - 1 ? k + EX_KL + EX_KU : n - 1;
        int pr = k;
        double big = fabs(AB(k, k)), pv;
        for (i = k + 1; i <= imax; i++)
            if (fabs(AB(i, k)) > big) {
                big = fabs(AB(i, k));
                pr = i;
            }
        piv[k] = pr;
        if (!(big > 0.0) || !isfinite(big)) return FP_NOCONVERGE;
        if (pr != k)
            for (j = k; j <= jmax; j++) {
                double t = AB(k, j);
                AB(k, j) = AB(pr, j);
                AB(pr, j) = t;
            }
        pv = AB(k, k);
        for (i = k + 1; i <= imax; i++) {
            double l = AB(i, k) / pv;
            AB(i, k) = l;
            if (l != 0.0)
                for (j = k + 1; j <= jmax; j++) AB(i, j) -= l * AB(k, j);
        }
    }
    return FP_OK;
}

static void ex_band_solve(int n, const double *band, const double *piv, double *b)
{
    int k, i, j;
    for (k = 0; k < n; k++) {
        int pr = (int)piv[k], imax = k + EX_KL < n - 1 ? k + EX_KL : n - 1;
        if (pr != k) {
            double t = b[k];
            b[k] = b[pr];
            b[pr] = t;
        }
        for (i = k + 1; i <= imax; i++) b[i] -= AB(i, k) * b[k];
    }
    for (k = n - 1; k >= 0; k--) {
        int jmax = k + EX_KL + EX_KU < n - 1 ? k + EX_KL + EX_KU : n - 1;
        double s = b[k];
        for (j = k + 1; j <= jmax; j++) s -= AB(k, j) * b[j];
        b[k] = s / AB(k, k);
    }
}

/* The force law at q, qd: F, and (if dFq != NULL) its gradients (nq each). */
static double ex_force(const fp_exact *p, const fp_exact_force *F, const double *q,
                       const double *qd, double *dFq, double *dFv)
{
    const int nq = p->nq;
    double ax = q[nq - 2], ay = q[nq - 1], adx = qd[nq - 2], ady = qd[nq - 1];
    double n = ax * ax + ay * ay > 0.0 ? ax * ax + ay * ay : NAN;    /* NaN, no 1/0 */
    double om = (ax * ady - ay * adx) / n, phi = atan2(-ax, ay);
    double e = F->kx * q[0] + F->kp * phi + F->kd * om;
    if (dFq != NULL) {
        int i;
        for (i = 0; i < nq; i++) dFq[i] = dFv[i] = 0.0;
        dFq[nq - 2] = -F->Q0 * (F->kp * (-ay / n) + F->kd * (ady / n - 2 * om * ax / n));
        dFq[nq - 1] = -F->Q0 * (F->kp * (ax / n) + F->kd * (-adx / n - 2 * om * ay / n));
        dFq[0] += -F->Q0 * F->kx;
        dFv[nq - 2] = -F->Q0 * F->kd * (-ay / n);
        dFv[nq - 1] = -F->Q0 * F->kd * (ax / n);
    }
    return F->F0 - F->Q0 * e;
}

static int ex_force_ok(const fp_exact_force *F)
{
    return F != NULL && isfinite(F->F0) && isfinite(F->Q0) && isfinite(F->kx) && isfinite(F->kp)
           && isfinite(F->kd);
}

int fp_exact_forces(const fp_exact *p, const double *q, const double *qd, double u,
                    double *f, double *K, double *C, double *M, double *work)
{
    if (p == NULL || q == NULL || qd == NULL || f == NULL || work == NULL
        || (K == NULL) != (C == NULL) || !isfinite(u))
        return FP_BADARG;
    return ex_forces(p, q, qd, u, f, K, C, M, NULL, 0, 0, 0, work, work + p->nq + 1);
}

int fp_exact_start(const fp_exact *p, const fp_exact_force *F, double *s, double *work)
{
    int nq, rc, i;
    double *band, *piv, *e, *ed, u;
    if (p == NULL || s == NULL || work == NULL || !ex_force_ok(F)) return FP_BADARG;
    nq = p->nq;
    band = work;
    piv = band + (long)EX_W * nq;
    e = piv + nq;
    ed = e + nq + 1;
    if (!finite_array(s, 2L * nq)) return FP_BADARG;
    u = ex_force(p, F, s, s + nq, NULL, NULL);
    if (!isfinite(u)) return FP_NONFINITE;
    rc = ex_forces(p, s, s + nq, u, s + 2 * nq, NULL, NULL, NULL, band, 1.0, 0.0, 0.0, e, ed);
    if (rc != FP_OK) return rc;
    if (ex_band_lu(nq, band, piv) != FP_OK) return FP_NOCONVERGE;
    ex_band_solve(nq, band, piv, s + 2 * nq);
    for (i = 0; i < nq; i++) s[3 * nq + i] = s[2 * nq + i];
    return finite_array(s + 2 * nq, 2L * nq) ? FP_OK : FP_NONFINITE;
}

static double ex_maxabs(const double *v, int n)
{
    double m = 0.0;
    int i;
    for (i = 0; i < n; i++)
        if (fabs(v[i]) > m) m = fabs(v[i]);
    return m;
}

/* One step (exact.py, GeneralizedAlpha.step) from s into the vectors of work; s is updated
 * only on success. */
static int ex_step(const fp_exact *p, const fp_exact_force *F, double *s, double *work,
                   long *iters)
{
    const int nq = p->nq;
    const double h = p->h, b = p->beta, gm = p->gamma, bp = p->bp, am = p->am, af = p->af;
    double *band = work, *piv = band + (long)EX_W * nq, *y = piv + nq, *wr = y + nq;
    double *qdd = wr + nq, *qpred = qdd + nq, *vpred = qpred + nq, *ac = vpred + nq;
    double *a = ac + nq, *q = a + nq, *v = q + nq, *f = v + nq, *r = f + nq, *dFq = r + nq;
    double *dFv = dFq + nq, *e = dFv + nq, *ed = e + nq + 1;
    const double *q0 = s, *v0 = s + nq, *qdd0 = s + 2 * nq, *a0 = s + 3 * nq;
    double last = INFINITY, wy = 0.0;
    int have_lu = 0, it, i, converged = 0, has_w = 0;
    for (i = 0; i < nq; i++) {
        qdd[i] = qdd0[i];
        qpred[i] = q0[i] + h * v0[i] + h * h * (0.5 - b) * a0[i];
        vpred[i] = v0[i] + h * (1 - gm) * a0[i];
        ac[i] = (af * qdd0[i] - am * a0[i]) / (1 - am);
    }
    for (it = 0; it < p->max_iter; it++) {
        int need = !have_lu, rc;
        double u, size, scale;
        for (i = 0; i < nq; i++) {
            a[i] = ac[i] + bp * qdd[i];
            q[i] = qpred[i] + h * h * b * a[i];
            v[i] = vpred[i] + h * gm * a[i];
        }
        u = ex_force(p, F, q, v, need ? dFq : NULL, dFv);
        if (!isfinite(u)) return FP_NONFINITE;
        rc = ex_forces(p, q, v, u, f, NULL, NULL, NULL, need ? band : NULL, 1.0, bp * h * h * b,
                       bp * h * gm, e, ed);
        if (rc != FP_OK) return rc;
        ex_mass_times(p, qdd, r);
        for (i = 0; i < nq; i++) r[i] = r[i] - f[i];
        if (need) {
            /* K[0] -= dFq, C[0] -= dFv: in the band, or outside it in the row w */
            double ck = bp * h * h * b, cc = bp * h * gm;
            has_w = 0;
            for (i = 0; i < nq; i++) {
                double sij = ck * (-dFq[i]) + cc * (-dFv[i]);
                wr[i] = 0.0;
                if (sij == 0.0) continue;
                if (i <= EX_KU) AB(0, i) += sij;
                else {
                    wr[i] = sij;
                    has_w = 1;
                }
            }
            if (ex_band_lu(nq, band, piv) != FP_OK) return FP_NOCONVERGE;
            if (has_w) {
                for (i = 0; i < nq; i++) y[i] = 0.0;
                y[0] = 1.0;
                ex_band_solve(nq, band, piv, y);
                wy = 1.0;
                for (i = 0; i < nq; i++) wy += wr[i] * y[i];
                if (!(fabs(wy) > 0.0) || !isfinite(wy)) return FP_NOCONVERGE;
            }
            have_lu = 1;
        }
        ex_band_solve(nq, band, piv, r);
        if (has_w) {
            double wz = 0.0;
            for (i = 0; i < nq; i++) wz += wr[i] * r[i];
            for (i = 0; i < nq; i++) r[i] -= y[i] * (wz / wy);
        }
        for (i = 0; i < nq; i++) qdd[i] += -r[i];
        if (!finite_array(qdd, nq)) return FP_NONFINITE;
        *iters += 1;
        size = h * gm * bp * ex_maxabs(r, nq);
        scale = p->tol * fmax(1.0, ex_maxabs(v, nq));
        if (size <= scale) {
            converged = 1;
            break;
        }
        if (need && it > 0 && size >= 0.5 * last && size <= 1e3 * scale) {
            converged = 1;
            break;
        }
        if (size > 0.1 * last) have_lu = 0;
        last = size;
    }
    if (!converged) return FP_NOCONVERGE;
    for (i = 0; i < nq; i++) {
        a[i] = ac[i] + bp * qdd[i];
        q[i] = qpred[i] + h * h * b * a[i];
        v[i] = vpred[i] + h * gm * a[i];
    }
    if (!finite_array(q, nq) || !finite_array(v, nq) || !finite_array(a, nq))
        return FP_NONFINITE;
    for (i = 0; i < nq; i++) {
        s[i] = q[i];
        s[nq + i] = v[i];
        s[2 * nq + i] = qdd[i];
        s[3 * nq + i] = a[i];
    }
    return FP_OK;
}

FP_NOINLINE
static int exact_steps_(const fp_exact *p, const fp_exact_force *F, long n_steps, double *s,
                   double *work, long *done, long *iters)
{
    long k;
    if (done != NULL) *done = 0;
    if (p == NULL || s == NULL || work == NULL || done == NULL || iters == NULL || n_steps < 0
        || !ex_force_ok(F))
        return FP_BADARG;
    for (k = 0; k < n_steps; k++) {
        int rc = ex_step(p, F, s, work, iters);
        if (rc != FP_OK) return rc;
        *done = k + 1;
    }
    return FP_OK;
}

/* ================================================================ Radau IIA (plant_fmu/exact.py)
 * Complex numbers as (re, im) pairs of doubles (C99's complex type is not taken: the FMUs'
 * sources compile with any C99-minus-Annex-G compiler). */
#define CAB(i, j) band[2L * ((long)(j) * EX_W + (EX_KL + EX_KU + (i) - (j)))]

/* Complex band LU with partial pivoting in place (interleaved (re, im) band of ex_band_lu's
 * layout); piv as doubles. FP_OK or FP_NOCONVERGE (a zero pivot). */
static int ex_cband_lu(int n, double *band, double *piv)
{
    int k, i, j;
    for (k = 0; k < n; k++) {
        int imax = k + EX_KL < n - 1 ? k + EX_KL : n - 1;
        int jmax = k + EX_KL + EX_KU < n - 1 ? k + EX_KL + EX_KU : n - 1;
        int pr = k;
        double big = hypot((&CAB(k, k))[0], (&CAB(k, k))[1]), pr_re, pr_im, d;
        for (i = k + 1; i <= imax; i++) {
            double a = hypot((&CAB(i, k))[0], (&CAB(i, k))[1]);
            if (a > big) {
                big = a;
                pr = i;
            }
        }
        piv[k] = pr;
        if (!(big > 0.0) || !isfinite(big)) return FP_NOCONVERGE;
        if (pr != k)
            for (j = k; j <= jmax; j++) {
                double *a = &CAB(k, j), *b = &CAB(pr, j), t0 = a[0], t1 = a[1];
                a[0] = b[0];
                a[1] = b[1];
                b[0] = t0;
                b[1] = t1;
            }
        /* 1 / pivot */
        pr_re = (&CAB(k, k))[0];
        pr_im = (&CAB(k, k))[1];
        d = pr_re * pr_re + pr_im * pr_im;
        pr_re /= d;
        pr_im = -pr_im / d;
        for (i = k + 1; i <= imax; i++) {
            double *l = &CAB(i, k), lr = l[0] * pr_re - l[1] * pr_im,
                   li = l[0] * pr_im + l[1] * pr_re;
            l[0] = lr;
            l[1] = li;
            if (lr != 0.0 || li != 0.0)
                for (j = k + 1; j <= jmax; j++) {
                    double *a = &CAB(i, j);
                    const double *b = &CAB(k, j);
                    a[0] -= lr * b[0] - li * b[1];
                    a[1] -= lr * b[1] + li * b[0];
                }
        }
    }
    return FP_OK;
}

/* Solve with ex_cband_lu's factors; b interleaved (re, im), n complex entries. */
static void ex_cband_solve(int n, const double *band, const double *piv, double *b)
{
    int k, i, j;
    for (k = 0; k < n; k++) {
        int pr = (int)piv[k], imax = k + EX_KL < n - 1 ? k + EX_KL : n - 1;
        double bk0, bk1;
        if (pr != k) {
            double t0 = b[2 * k], t1 = b[2 * k + 1];
            b[2 * k] = b[2 * pr];
            b[2 * k + 1] = b[2 * pr + 1];
            b[2 * pr] = t0;
            b[2 * pr + 1] = t1;
        }
        bk0 = b[2 * k];
        bk1 = b[2 * k + 1];
        for (i = k + 1; i <= imax; i++) {
            const double *l = &CAB(i, k);
            b[2 * i] -= l[0] * bk0 - l[1] * bk1;
            b[2 * i + 1] -= l[0] * bk1 + l[1] * bk0;
        }
    }
    for (k = n - 1; k >= 0; k--) {
        int jmax = k + EX_KL + EX_KU < n - 1 ? k + EX_KL + EX_KU : n - 1;
        double s0 = b[2 * k], s1 = b[2 * k + 1], d0, d1, dd;
        for (j = k + 1; j <= jmax; j++) {
            const double *a = &CAB(k, j);
            s0 -= a[0] * b[2 * j] - a[1] * b[2 * j + 1];
            s1 -= a[0] * b[2 * j + 1] + a[1] * b[2 * j];
        }
        d0 = (&CAB(k, k))[0];
        d1 = (&CAB(k, k))[1];
        dd = d0 * d0 + d1 * d1;
        b[2 * k] = (s0 * d0 + s1 * d1) / dd;
        b[2 * k + 1] = (s1 * d0 - s0 * d1) / dd;
    }
}
#undef CAB

/* A Radau iteration whose correction shrinks less than this factor gets a new tangent. */
#define RADAU_SLOW 0.1

/* The Radau IIA constants (plant_fmu/exact.py: RADAU_C, RADAU_A, RADAU_T, RADAU_TI,
 * RADAU_GAMMA, RADAU_MU, RADAU_DEND), computed once. */
typedef struct ex_radau {
    double c[3], A[9], A2[9], T[9], TI[9], gamma, mu_re, mu_im, dend[3];
} ex_radau;

static void ex_radau_constants(ex_radau *r)
{
    const double s6 = sqrt(6.0), c81 = cbrt(81.0), c9 = cbrt(9.0);
    const double T[9] = {9.1232394870892942792e-02, -0.14125529502095420843,
                         -3.0029194105147424492e-02, 0.24171793270710701896,
                         0.20412935229379993199, 0.38294211275726193779,
                         0.96604818261509293619, 1.0, 0.0};
    const double TI[9] = {4.3255798900631553510, 0.33919925181580986954, 0.54177053993587487119,
                          -4.1787185915519047273, -0.32768282076106238708,
                          0.47662355450055045196, -0.50287263494578687595,
                          2.5719269498556054292, -0.59603920482822492497};
    double al = (12.0 - c81 + c9) / 60.0, be = (c81 + c9) * sqrt(3.0) / 60.0, cn = al * al + be * be;
    int i, j, k;
    r->c[0] = (4.0 - s6) / 10.0;
    r->c[1] = (4.0 + s6) / 10.0;
    r->c[2] = 1.0;
    r->A[0] = (88.0 - 7.0 * s6) / 360.0;
    r->A[1] = (296.0 - 169.0 * s6) / 1800.0;
    r->A[2] = (-2.0 + 3.0 * s6) / 225.0;
    r->A[3] = (296.0 + 169.0 * s6) / 1800.0;
    r->A[4] = (88.0 + 7.0 * s6) / 360.0;
    r->A[5] = (-2.0 - 3.0 * s6) / 225.0;
    r->A[6] = (16.0 - s6) / 36.0;
    r->A[7] = (16.0 + s6) / 36.0;
    r->A[8] = 1.0 / 9.0;
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) {
            double v = 0.0;
            for (k = 0; k < 3; k++) v += r->A[3 * i + k] * r->A[3 * k + j];
            r->A2[3 * i + j] = v;
        }
    for (i = 0; i < 9; i++) {
        r->T[i] = T[i];
        r->TI[i] = TI[i];
    }
    r->gamma = 30.0 / (6.0 + c81 - c9);
    r->mu_re = al / cn;
    r->mu_im = be / cn;
    r->dend[0] = (1.0 - r->c[1]) / ((r->c[0] - r->c[1]) * (r->c[0] - 1.0));
    r->dend[1] = (1.0 - r->c[0]) / ((r->c[1] - r->c[0]) * (r->c[1] - 1.0));
    r->dend[2] = (2.0 - r->c[0] - r->c[1]) / ((1.0 - r->c[0]) * (1.0 - r->c[1]));
}

/* The stages' velocities Vs and positions Qs (3 x nq each) of the stage accelerations W from
 * the step's start (q0, v0): V_i = v0 + h sum_j A_ij W_j, Q_i = q0 + c_i h v0 + h^2 sum_j
 * (A^2)_ij W_j. */
static void ex_radau_stages(const ex_radau *R, int nq, double h, const double *q0,
                            const double *v0, const double *W, double *Qs, double *Vs)
{
    int i, j, k;
    for (i = 0; i < 3; i++)
        for (k = 0; k < nq; k++) {
            double a = 0.0, b = 0.0;
            for (j = 0; j < 3; j++) {
                a += R->A[3 * i + j] * W[j * nq + k];
                b += R->A2[3 * i + j] * W[j * nq + k];
            }
            Vs[i * nq + k] = v0[k] + h * a;
            Qs[i * nq + k] = q0[k] + h * R->c[i] * v0[k] + h * h * b;
        }
}

/* e = kx x + kp phi_o + kd omega_o at (q, qd) and, if gq != NULL, de/dq and de/dqd. */
static double ex_stage_error(const fp_exact *p, const fp_radau_force *F, const double *q,
                             const double *qd, double *gq, double *gv)
{
    fp_exact_force one;
    double e;
    one.F0 = 0.0;
    one.Q0 = -1.0;                       /* ex_force gives F0 - Q0 e = e, dF = de */
    one.kx = F->kx;
    one.kp = F->kp;
    one.kd = F->kd;
    e = ex_force(p, &one, q, qd, gq, gv);
    return e;
}

static int ex_radau_force_ok(const fp_radau_force *F)
{
    int i;
    if (F == NULL || !isfinite(F->kx) || !isfinite(F->kp) || !isfinite(F->kd)) return 0;
    for (i = 0; i < 3; i++)
        if (!isfinite(F->F0[i])) return 0;
    for (i = 0; i < 9; i++)
        if (!isfinite(F->Q[i])) return 0;
    return 1;
}

static int ex_radau_feedback(const fp_radau_force *F)
{
    int i;
    for (i = 0; i < 9; i++)
        if (F->Q[i] != 0.0) return 1;
    return 0;
}

/* work: the real band (EX_W nq) and its pivots (nq), the complex band (2 EX_W nq) and its
 * pivots (nq), Sherman-Morrison's y and w, real (2 nq) and complex (4 nq), the stages W, Q, V, R
 * and the correction (15 nq), the force gradients (2 nq), f (nq), the complex right-hand side
 * (2 nq), the nodal vectors e and ed (2 (nq + 1)). */
long fp_radau_work_size(const fp_exact *p)
{
    long ga = fp_exact_work_size(p), n;
    if (p == NULL) return 0;
    n = (long)p->nq * (3 * EX_W + 31) + 2 * ((long)p->nq + 1) + 8;
    return n > ga ? n : ga;
}

int fp_radau_start(const fp_exact *p, const fp_radau_force *F, double *s, double *work)
{
    fp_exact_force one;
    int rc, i, nq;
    if (p == NULL || s == NULL || work == NULL || !ex_radau_force_ok(F)) return FP_BADARG;
    nq = p->nq;
    one.F0 = F->F0[0];
    one.Q0 = F->Q[0] + F->Q[1] + F->Q[2];
    one.kx = F->kx;
    one.kp = F->kp;
    one.kd = F->kd;
    rc = fp_exact_start(p, &one, s, work);
    if (rc != FP_OK) return rc;
    for (i = 0; i < nq; i++) s[3 * nq + i] = 0.0;
    return FP_OK;
}

/* Add the row 0 entries w (the force law's, coefficient c times (h^2 gq + h mu gv)) to a band
 * (stride 1: real; 2: complex with mu complex): inside the band directly, outside into wr
 * (stride as the band); 1 if some entry lies outside. */
static int ex_force_row(const fp_exact *p, double *band, int stride, const double *gq,
                        const double *gv, double c_re, double c_im, double mu_re, double mu_im,
                        double *wr)
{
    const int nq = p->nq;
    const double h = p->h;
    int i, outside = 0;
    for (i = 0; i < nq; i++) {
        /* c (h^2 gq_i + h mu gv_i) */
        double a_re = h * h * gq[i] + h * mu_re * gv[i], a_im = h * mu_im * gv[i];
        double v_re = c_re * a_re - c_im * a_im, v_im = c_re * a_im + c_im * a_re;
        wr[stride * i] = 0.0;
        if (stride == 2) wr[2 * i + 1] = 0.0;
        if (v_re == 0.0 && v_im == 0.0) continue;
        if (i <= EX_KU) {
            ABS_(band, stride, 0, i) += v_re;
            if (stride == 2) ABS_(band + 1, 2, 0, i) += v_im;
        } else {
            wr[stride * i] = v_re;
            if (stride == 2) wr[2 * i + 1] = v_im;
            outside = 1;
        }
    }
    return outside;
}

FP_NOINLINE
static int radau_step_(const fp_exact *p, const fp_radau_force *F, double *s, double *work,
                  long *iters, double *e_out)
{
    ex_radau R;
    int nq, it, i, j, k, rc, feedback, has_w1 = 0, has_w2 = 0, converged = 0, need = 1;
    double h, *band1, *piv1, *band2, *piv2, *y1, *w1, *y2, *w2, *W, *Qs, *Vs, *Rs, *dW, *gq, *gv;
    double *f, *z2, *e, *ed, last = INFINITY, wy1 = 0.0, wy2_re = 0.0, wy2_im = 0.0;
    double q1 = 0.0, q2_re = 0.0, q2_im = 0.0, u[3], es[3] = {0.0, 0.0, 0.0}, QT[9], tmp[9];
    const double *q0, *v0, *qdd0, *jerk0;
    ex_target tg[3];
    if (p == NULL || s == NULL || work == NULL || iters == NULL || !ex_radau_force_ok(F))
        return FP_BADARG;
    ex_radau_constants(&R);
    nq = p->nq;
    h = p->h;
    q0 = s;
    v0 = s + nq;
    qdd0 = s + 2 * nq;
    jerk0 = s + 3 * nq;
    if (!finite_array(s, 4L * nq)) return FP_BADARG;
    band1 = work;
    piv1 = band1 + (long)EX_W * nq;
    band2 = piv1 + nq;
    piv2 = band2 + 2L * EX_W * nq;
    y1 = piv2 + nq;
    w1 = y1 + nq;
    y2 = w1 + nq;
    w2 = y2 + 2 * nq;
    W = w2 + 2 * nq;
    Qs = W + 3 * nq;
    Vs = Qs + 3 * nq;
    Rs = Vs + 3 * nq;
    dW = Rs + 3 * nq;
    gq = dW + 3 * nq;
    gv = gq + nq;
    f = gv + nq;
    z2 = f + nq;
    e = z2 + 2 * nq;
    ed = e + nq + 1;
    feedback = ex_radau_feedback(F);
    /* Q transformed: its entry on the real block and on the complex pair (the projection on
     * what commutes with A; exact for a law that is a function of A, as the filter's is) */
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) {
            double v = 0.0;
            for (k = 0; k < 3; k++) v += F->Q[3 * i + k] * R.T[3 * k + j];
            tmp[3 * i + j] = v;
        }
    for (i = 0; i < 3; i++)
        for (j = 0; j < 3; j++) {
            double v = 0.0;
            for (k = 0; k < 3; k++) v += R.TI[3 * i + k] * tmp[3 * k + j];
            QT[3 * i + j] = v;
        }
    q1 = QT[0];
    q2_re = 0.5 * (QT[4] + QT[8]);
    q2_im = 0.5 * (QT[7] - QT[5]);
    /* the first guess: the accelerations extrapolated by the jerk */
    for (i = 0; i < 3; i++)
        for (k = 0; k < nq; k++) W[i * nq + k] = qdd0[k] + R.c[i] * h * jerk0[k];
    for (it = 0; it < p->max_iter; it++) {
        double size, scale, vmax = 0.0;
        ex_radau_stages(&R, nq, h, q0, v0, W, Qs, Vs);         /* the stages */
        if (need) {
            /* the tangent at the second stage (of the first guess, or of the iterate when the
             * iteration contracts slowly), the force law's gradient there */
            const double mr = R.mu_re, mi = R.mu_im, g = R.gamma;
            double uk = F->F0[1];
            for (k = 0; k < nq; k++) gq[k] = gv[k] = 0.0;
            if (feedback) {
                double e1 = ex_stage_error(p, F, Qs + nq, Vs + nq, gq, gv);
                uk = F->F0[1] - (F->Q[3] + F->Q[4] + F->Q[5]) * e1;
                if (!isfinite(uk)) return FP_NONFINITE;
            }
            tg[0].band = band1;
            tg[0].cm = g * g;
            tg[0].ck = h * h;
            tg[0].cc = h * g;
            tg[0].stride = 1;
            tg[1].band = band2;
            tg[1].cm = mr * mr - mi * mi;
            tg[1].ck = h * h;
            tg[1].cc = h * mr;
            tg[1].stride = 2;
            tg[2].band = band2 + 1;
            tg[2].cm = 2.0 * mr * mi;
            tg[2].ck = 0.0;
            tg[2].cc = h * mi;
            tg[2].stride = 2;
            rc = ex_forces_to(p, Qs + nq, Vs + nq, uk, f, NULL, NULL, NULL, tg, 3, e, ed);
            if (rc != FP_OK) return rc;
            has_w1 = feedback && ex_force_row(p, band1, 1, gq, gv, q1, 0.0, g, 0.0, w1);
            has_w2 = feedback && ex_force_row(p, band2, 2, gq, gv, q2_re, q2_im, mr, mi, w2);
            if (!feedback) {
                for (k = 0; k < nq; k++) w1[k] = w2[2 * k] = w2[2 * k + 1] = 0.0;
            }
            if (ex_band_lu(nq, band1, piv1) != FP_OK) return FP_NOCONVERGE;
            if (ex_cband_lu(nq, band2, piv2) != FP_OK) return FP_NOCONVERGE;
            need = 0;
            if (has_w1) {
                for (k = 0; k < nq; k++) y1[k] = 0.0;
                y1[0] = 1.0;
                ex_band_solve(nq, band1, piv1, y1);
                wy1 = 1.0;
                for (k = 0; k < nq; k++) wy1 += w1[k] * y1[k];
                if (!(fabs(wy1) > 0.0) || !isfinite(wy1)) return FP_NOCONVERGE;
            }
            if (has_w2) {
                for (k = 0; k < 2 * nq; k++) y2[k] = 0.0;
                y2[0] = 1.0;
                ex_cband_solve(nq, band2, piv2, y2);
                wy2_re = 1.0;
                wy2_im = 0.0;
                for (k = 0; k < nq; k++) {
                    wy2_re += w2[2 * k] * y2[2 * k] - w2[2 * k + 1] * y2[2 * k + 1];
                    wy2_im += w2[2 * k] * y2[2 * k + 1] + w2[2 * k + 1] * y2[2 * k];
                }
                if (!(hypot(wy2_re, wy2_im) > 0.0) || !isfinite(wy2_re + wy2_im))
                    return FP_NOCONVERGE;
            }
        }
        /* the stage forces and residuals R_i = M W_i - f(Q_i, V_i, F_i) */
        for (i = 0; i < 3; i++) {
            es[i] = feedback ? ex_stage_error(p, F, Qs + i * nq, Vs + i * nq, NULL, NULL) : 0.0;
            if (!isfinite(es[i])) return FP_NONFINITE;
        }
        for (i = 0; i < 3; i++) {
            u[i] = F->F0[i];
            for (j = 0; j < 3; j++) u[i] -= F->Q[3 * i + j] * es[j];
            if (!isfinite(u[i])) return FP_NONFINITE;
            rc = ex_forces(p, Qs + i * nq, Vs + i * nq, u[i], f, NULL, NULL, NULL, NULL, 0, 0, 0,
                           e, ed);
            if (rc != FP_OK) return rc;
            ex_mass_times(p, W + i * nq, Rs + i * nq);
            for (k = 0; k < nq; k++) Rs[i * nq + k] -= f[k];
        }
        /* transformed: Z = TI R; d1 = S1^-1 (-gamma^2 Z1), d2 = S2^-1 (-mu^2 (Z2 + i Z3)) */
        for (k = 0; k < nq; k++) {
            double z0 = 0.0, za = 0.0, zb = 0.0, m2r = R.mu_re * R.mu_re - R.mu_im * R.mu_im,
                   m2i = 2.0 * R.mu_re * R.mu_im;
            for (j = 0; j < 3; j++) {
                z0 += R.TI[j] * Rs[j * nq + k];
                za += R.TI[3 + j] * Rs[j * nq + k];
                zb += R.TI[6 + j] * Rs[j * nq + k];
            }
            dW[k] = -R.gamma * R.gamma * z0;                  /* real system's right side */
            z2[2 * k] = -(m2r * za - m2i * zb);
            z2[2 * k + 1] = -(m2r * zb + m2i * za);
        }
        ex_band_solve(nq, band1, piv1, dW);
        if (has_w1) {
            double wz = 0.0;
            for (k = 0; k < nq; k++) wz += w1[k] * dW[k];
            for (k = 0; k < nq; k++) dW[k] -= y1[k] * (wz / wy1);
        }
        ex_cband_solve(nq, band2, piv2, z2);
        if (has_w2) {
            double wz_re = 0.0, wz_im = 0.0, d = wy2_re * wy2_re + wy2_im * wy2_im, c_re, c_im;
            for (k = 0; k < nq; k++) {
                wz_re += w2[2 * k] * z2[2 * k] - w2[2 * k + 1] * z2[2 * k + 1];
                wz_im += w2[2 * k] * z2[2 * k + 1] + w2[2 * k + 1] * z2[2 * k];
            }
            c_re = (wz_re * wy2_re + wz_im * wy2_im) / d;      /* wz / wy */
            c_im = (wz_im * wy2_re - wz_re * wy2_im) / d;
            for (k = 0; k < nq; k++) {
                z2[2 * k] -= y2[2 * k] * c_re - y2[2 * k + 1] * c_im;
                z2[2 * k + 1] -= y2[2 * k] * c_im + y2[2 * k + 1] * c_re;
            }
        }
        /* dW = T [d1; Re d2; Im d2], W += dW */
        size = 0.0;
        for (k = 0; k < nq; k++) {
            const double d1 = dW[k], dr = z2[2 * k], di = z2[2 * k + 1];
            for (i = 0; i < 3; i++) {
                double d = R.T[3 * i] * d1 + R.T[3 * i + 1] * dr + R.T[3 * i + 2] * di;
                W[i * nq + k] += d;
                if (fabs(d) > size) size = fabs(d);
            }
        }
        if (!finite_array(W, 3L * nq)) return FP_NONFINITE;
        *iters += 1;
        for (k = 0; k < 3 * nq; k++)
            if (fabs(Vs[k]) > vmax) vmax = fabs(Vs[k]);
        size *= h;
        scale = p->tol * fmax(1.0, vmax);
        if (size <= scale) {
            converged = 1;
            break;
        }
        if (it > 0 && size >= 0.5 * last && size <= 1e3 * scale) {
            converged = 1;                          /* round-off: nothing more to gain */
            break;
        }
        if (it > 0 && size > RADAU_SLOW * last)
            need = 1;               /* slow: a tangent at the iterate (generalized alpha's rule) */
        last = size;
    }
    if (!converged) return FP_NOCONVERGE;
    /* the step's end: the last stage of the converged accelerations */
    ex_radau_stages(&R, nq, h, q0, v0, W, Qs, Vs);
    if (!finite_array(Qs, 3L * nq) || !finite_array(Vs, 3L * nq)) return FP_NONFINITE;
    if (e_out != NULL) {
        for (i = 0; i < 3; i++) {
            e_out[i] = feedback ? ex_stage_error(p, F, Qs + i * nq, Vs + i * nq, NULL, NULL)
                                : 0.0;
            if (!isfinite(e_out[i])) return FP_NONFINITE;
        }
    }
    for (k = 0; k < nq; k++) {
        double jk = (R.dend[0] * W[k] + R.dend[1] * W[nq + k] + R.dend[2] * W[2 * nq + k]) / h;
        if (!isfinite(jk)) return FP_NONFINITE;
        s[k] = Qs[2 * nq + k];
        s[nq + k] = Vs[2 * nq + k];
        s[2 * nq + k] = W[2 * nq + k];
        s[3 * nq + k] = jk;
    }
    return FP_OK;
}

/* The outputs of the exact beam at s = [q, qd, ...] (plant_fmu/exact.py, ExactPlant): x, its rate,
 * the tip tangent's angle and rate, the root tangent's angle (the floating frame's phi), the tip's
 * distance from the line of the root tangent and, if want_energy, T + V. */
int fp_exact_outputs(const fp_exact *p, const double *s, int want_energy, double *out,
                     double *work)
{
    const int nq = p == NULL ? 0 : p->nq;
    const double *q, *qd;
    double ax, ay, n, t0x, t0y, t0n;
    if (p == NULL || s == NULL || out == NULL || (want_energy && work == NULL)) return FP_BADARG;
    q = s;
    qd = s + nq;
    ax = q[nq - 2];
    ay = q[nq - 1];
    n = ax * ax + ay * ay;
    t0n = sqrt(q[1] * q[1] + q[2] * q[2]);
    if (!(n > 0.0 && t0n > 0.0)) return FP_NONFINITE;   /* a tangent of zero length */
    out[FP_OUT_X] = q[0];
    out[FP_OUT_XDOT] = qd[0];
    out[FP_OUT_PHI_O] = atan2(-ax, ay);
    out[FP_OUT_OMEGA_O] = (ax * qd[nq - 1] - ay * qd[nq - 2]) / n;
    out[FP_OUT_PHI] = atan2(-q[1], q[2]);
    /* b2 = (-t0y, t0x) with t0 the unit root tangent; the tip r_ne = q[nq - 4 .. nq - 3], the
     * root (x, 0) */
    t0x = q[1] / t0n;
    t0y = q[2] / t0n;
    out[FP_OUT_TIP] = (q[nq - 4] - q[0]) * (-t0y) + q[nq - 3] * t0x;
    if (want_energy) {
        double *e = work, *mv = work + nq + 1, T = 0.0, U = 0.0, Vg = 0.0;
        const double le = p->le, int_h[4] = {le * 0.5, le * (le / 12), le * 0.5, le * (-le / 12)};
        int el, g, k, i;
        e[0] = q[0];
        e[1] = 0.0;
        for (k = 2; k < nq + 1; k++) e[k] = q[k - 1];
        ex_mass_times(p, qd, mv);
        for (i = 0; i < nq; i++) T += qd[i] * mv[i];
        for (el = 0; el < p->ne; el++) {
            const double *ee = e + 4 * el;
            for (g = 0; g < EX_NG; g++) {
                const double *d1 = p->gd1 + 4 * g, *d2 = p->gd2 + 4 * g;
                double a0 = 0, a1 = 0, b0 = 0, b1 = 0, nn, eps, kap;
                for (k = 0; k < 4; k++) {
                    a0 += d1[k] * ee[2 * k];
                    a1 += d1[k] * ee[2 * k + 1];
                    b0 += d2[k] * ee[2 * k];
                    b1 += d2[k] * ee[2 * k + 1];
                }
                nn = a0 * a0 + a1 * a1;
                if (!(nn > 0.0)) return FP_NONFINITE;
                eps = sqrt(nn) - 1.0;
                kap = (a0 * b1 - a1 * b0) / nn;
                U += (p->EA * eps * eps + p->EI * kap * kap) * p->gw[g];
            }
            for (k = 0; k < 4; k++) Vg += int_h[k] * ee[2 * k + 1];
        }
        out[FP_OUT_ENERGY] = 0.5 * T + 0.5 * U + p->g * p->rhoA * Vg;
    }
    return finite_array(out, want_energy ? FP_OUT_ENERGY + 1 : FP_OUT_ENERGY) ? FP_OK
                                                                               : FP_NONFINITE;
}

#undef AB

/* ---------------------------------------------------------------------- the steppers, with
 * subnormals flushed (see ftz_enter) */
FP_NOINLINE
int fp_fixed_steps(const fp_plant *p, int method, const fp_tableau *tab, const fp_input *u,
                   double t, double h, long n_steps, double *y, double *work, long *done)
{
    fp_fenv env;
    int rc;
    if (!flushable(t, h))
        return fixed_steps_(p, method, tab, u, t, h, n_steps, y, work, done);
    env = ftz_enter();
    rc = fixed_steps_(p, method, tab, u, t, h, n_steps, y, work, done);
    ftz_leave(env);
    return rc;
}

FP_NOINLINE
int fp_dopri_advance(const fp_plant *p, const fp_tableau *tab, const fp_input *u, double *t,
                     double t_end, double *y, double *f, fp_adaptive *a, double *work)
{
    fp_fenv env;
    int rc;
    if (!flushable(*t, t_end))
        return dopri_advance_(p, tab, u, t, t_end, y, f, a, work);
    env = ftz_enter();
    rc = dopri_advance_(p, tab, u, t, t_end, y, f, a, work);
    ftz_leave(env);
    return rc;
}

FP_NOINLINE
int fp_exact_steps(const fp_exact *p, const fp_exact_force *F, long n_steps, double *s,
                   double *work, long *done, long *iters)
{
    fp_fenv env;
    int rc;
    if (!flushable(p->h, p->h))
        return exact_steps_(p, F, n_steps, s, work, done, iters);
    env = ftz_enter();
    rc = exact_steps_(p, F, n_steps, s, work, done, iters);
    ftz_leave(env);
    return rc;
}

FP_NOINLINE
int fp_radau_step(const fp_exact *p, const fp_radau_force *F, double *s, double *work,
                  long *iters, double *e_out)
{
    fp_fenv env;
    int rc;
    if (!flushable(p->h, p->h))
        return radau_step_(p, F, s, work, iters, e_out);
    env = ftz_enter();
    rc = radau_step_(p, F, s, work, iters, e_out);
    ftz_leave(env);
    return rc;
}
