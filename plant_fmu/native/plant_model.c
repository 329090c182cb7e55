/*
 * plant_model.c - FlexiblePendulum as a native FMU model (see fpm.h): its parameters' checks, its
 * step and its outputs, on the plant's compiled kernel (plant_fmu/native/fp_plant.c).
 *
 * The behaviour is that of the pythonfmu slave (plant_fmu/fmu.py) and of its steppers
 * (plant_fmu/integrators/base.py, rk.py, exponential.py), ported here so that both flavours
 * give the same outputs: the fixed substep grid t = t_base + k h (time from integers) with a
 * shortened last substep when a communication point is off the grid (the grid restarts there),
 * the input polynomial of the explicit methods and symplectic Euler (held at its step average
 * for the exponential integrator), the adaptive Dormand-Prince loop with its proposed step
 * carried from step to step, and the divergence checks.
 *
 * Modes: the unit beam's tables (fpm_vars.h, computed by plant_fmu/beam.py at build time for
 * n_elements 1..FPM_NE_MAX and n_modes 0..FPM_N_MODES_MAX), scaled at initialisation exactly as
 * beam.Scales does, with the same operations in the same order: the modal data are then
 * bit-identical to the pythonfmu plant's.
 *
 * Bounded work: a doStep takes at most FPM_MAX_SUBSTEPS substeps, counted in floating point and
 * checked against the cap before any conversion to an integer; beyond it the step is discarded
 * with the state unchanged, and the log says so (the cap and what the step needed). On the exact
 * rung a substep's cost grows with the element count and with its Newton iterations (and the
 * halvings of a substep that does not converge), so its cap follows the cost: a doStep spends at
 * most FPM_MAX_EXACT_WORK element-iterations (n_elements per Radau Newton iteration, halvings
 * included), refused before any work when the substeps alone would need more, and discarded
 * with the state unchanged when the iterations reach it (docs/fmus.md: the budget).
 *
 * No silent wrong answer: the outputs are computed at every accepted step (and at
 * initialisation) and a step whose outputs would not be finite is refused like a divergence; the
 * parameters are checked with the ranges of plant_fmu/params.py, and a quantity derived from
 * them that overflows or underflows is refused at initialisation, naming the parameters.
 *
 * FMU states save the independent state only (fpm_model_save): the time, the stepper's state
 * (substep grid, state vector, the adaptive step and its first-same-as-last derivative, the input
 * polynomial), the input derivatives and a refusal's reason. Everything else (sizes, the method,
 * the modal data, the plant, the linear model's matrices and discretisations, the outputs) is
 * rebuilt on restore by prepare(), the code of initialisation.
 */
#include <limits.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "fp_filter.h"
#include "fp_plant.h"
#include "fpm.h"
#include "fpm_vars.h"

#define NMAX FPM_N_MODES_MAX
#define NXMAX (2 * (NMAX + 2))
#define AUG (NXMAX + 1)
#ifndef FPM_MAX_SUBSTEPS
#define FPM_MAX_SUBSTEPS 1000000L
#endif
#ifndef FPM_MAX_EXACT_WORK
#define FPM_MAX_EXACT_WORK 2000000L     /* element-iterations per doStep: about 8 s here */
#endif
#define STATE_NORM2_LIMIT 1e200
#define SNAP 1e-7
#define EPS 2.220446049250313e-16
#define POSITIVE_MIN 1e-15          /* plant_fmu/params.py: POSITIVE_MIN */

enum { M_EULER, M_RK4, M_SYMPLECTIC, M_DOPRI5, M_EXPONENTIAL };
static const char *METHODS[] = {"euler", "rk4", "symplectic_euler", "dopri5", "exponential"};
#define N_METHODS 5

/* The stiffened rung's mass points: at most 4 NMAX points of 2 + n + n^2 values. */
#define SF_PTS_MAX (4 * NMAX * (2 + NMAX + NMAX * NMAX))

/* The exact rung's sizes: the state of n_elements = FPM_NE_MAX, the kernel's work for it
 * (fp_exact_work_size, checked at initialisation). */
#define XB_NQ_MAX (4 * FPM_NE_MAX + 3)
#define XB_S_MAX (4 * XB_NQ_MAX)
#define XB_WORK_MAX ((3 * 22 + 31) * XB_NQ_MAX + 2 * (XB_NQ_MAX + 1) + 8)

/* The exact rung's arrays (1.3 MB at 100 elements, most of it the modal law's C_f and the
 * scratch that computes it), left out of fpm_model_reset: its state, written whole by
 * xb_prepare before any use (and read only at the exact rung), the modal law, and scratch. */
#define XB_NA_MAX (2 * FPM_NE_MAX + 1)
typedef struct xb_arrays {
    double modal[XB_NA_MAX * XB_NA_MAX + (XB_NA_MAX - 1) * (XB_NA_MAX - 1)];  /* the modal law */
    double modal_key[8];        /* what modal was formed from (xb_prepare): n_elements, L, EA, */
    int modal_ok;               /* EI, rhoA, g, m, zeta; modal_ok: it holds them */
    double mwork[2 * XB_NA_MAX * XB_NA_MAX + 2 * XB_NA_MAX + 64];    /* its computation's */
    double s[XB_S_MAX];         /* the state [q, qd, qdd, jerk] */
    double saved[XB_S_MAX];     /* s at a step's start */
    double saved2[XB_S_MAX];    /* s at a substep's start (a halved substep that fails) */
    double work[XB_WORK_MAX];   /* the kernel's */
} xb_arrays;

/* One cached exact discretisation of the linear plant over a substep (the exponential method). */
typedef struct expo {
    double h;
    double Phi[NXMAX * NXMAX];
    double Gam[NXMAX];
} expo;

/* The work arrays of the stepping kernels and the exponential method, written before they are
 * read by every use: left out of fpm_model_reset (a restore resets the spare model, and clearing
 * these was most of its cost). */
typedef struct scratch {
    double work[(7 + 2) * NXMAX];   /* the stepping kernels' */
    double ework[9 * AUG * AUG];    /* fpf_expm's */
    double aug[AUG * AUG], E[AUG * AUG];
} scratch;

/* Derived arrays left out of fpm_model_reset (clearing them was most of a restore's memset):
 * prepare() (and prepared_like, which copies what prepare would write) writes the part of each
 * that is ever read before any read, and nothing reads the rest:
 *   pts   the stiffened rung's mass points: sf_points writes the p.npts rows fp_plant reads,
 *         which reads them only when p.stiffened (set with them);
 *   A, B  the exponential method's linear plant: prepare writes A[0 .. nx^2) and B[0 .. nx),
 *         read only by that method (discretisation, fpm_model_keep, prepared_like), nx x nx;
 *   ex    its cached discretisations: prepare sets both h to -1 (empty; a step h > 0 never
 *         matches it) before the method's first step, and only that method reads them. */
typedef struct derived {
    double pts[SF_PTS_MAX];
    double A[NXMAX * NXMAX], B[NXMAX];
    expo ex[2];
} derived;

/* What a step changes (copied before it, restored when it fails). */
typedef struct stepper {
    double t, t_base;
    long k;
    double y[NXMAX];
    double f[NXMAX];            /* dopri5: f(t, y, u(t)) (first same as last) */
    double h_abs;               /* dopri5: the proposed step */
    double u, du, d2u, tu;      /* the input polynomial of the stepper */
    int prev_poly;              /* the input the method's data belong to (rk.py's _u_prev) */
    double prev[4];
} stepper;

struct fpm_model {
    fpm_values v;
    double t0;
    double dF, d2F;             /* fmi2SetRealInputDerivatives of F_c */
    int ready;                  /* prepared from the parameters */
    int initialized;            /* exitInitializationMode succeeded */
    int stepped;                /* a doStep succeeded since initialisation (input_now) */
    int failed;                 /* refuses to step until a saved state is restored */
    char error[FPM_MSG_MAX];
    /* the plant */
    fp_plant p;
    double I3[NMAX], I5[NMAX], K[NMAX], D[NMAX], Kg[NMAX * NMAX], tip_slope[NMAX], tip_defl[NMAX];
    int n, nq, nx, method;
    double h, rtol, atol, phi_limit, energy_limit;
    stepper s;
    double y_acc[NXMAX];        /* the last accepted state (the outputs) */
    double out[FP_OUT_ETA + NMAX];
    int out_fresh, energy_fresh;
    /* fpm_model_output_derivatives' last fp_output_derivatives (one evaluation serves every
     * output and order of a request, and the requests that follow at the same point): valid
     * while od_valid (cleared by prepare) for the state od_x and the input od_u, od_du, compared
     * bit for bit */
    int od_valid;
    double od_u, od_du, od_x[NXMAX], od_d1[FP_OUT_ETA + NMAX], od_d2[FP_OUT_ETA + NMAX];
    /* the exponential method (its linear model and discretisations: in dv) */
    int ex_next;
    /* the exact rung (fidelity = "exact"; the block "the exact rung" below) */
    int exact;
    int xb_kv;                  /* the damping law is Kelvin-Voigt (else modal) */
    fp_exact xb_p, xb_ps;       /* Radau IIA at the step h, and at the substep taken */
    double xb_n1;               /* N_1(L): the first cantilever mode's tip deflection (eta_1) */
    double xb_work;             /* the element-iterations this doStep has spent (xb_step) */
    scratch scr;                /* the kernels' work arrays (not reset by fpm_model_reset) */
    derived dv;                 /* written by prepare() before any read (not reset either) */
    xb_arrays xb;               /* its state and scratch (not reset by fpm_model_reset) */
};

static int xb_prepare(fpm_model *m, const fpm_logger *lg);
static int xb_outputs_ok(fpm_model *m, const char **bad);
static int xb_substeps(fpm_model *m, double h, long n, char *why);
static int xb_step(fpm_model *m, const fpm_logger *lg, double t, double h);
static int xb_load(fpm_model *m, fpm_reader *r, const stepper *s, int stepped);
static int xb_refuse(const fpm_model *m, const fpm_logger *lg, const char *what);

size_t fpm_model_size(void) { return sizeof(fpm_model); }
fpm_values *fpm_model_values(fpm_model *m) { return &m->v; }
double fpm_model_time(const fpm_model *m) { return m->ready ? m->s.t : m->t0; }

void fpm_model_reset(fpm_model *m, double start_time)
{
    const size_t at = offsetof(fpm_model, scr), end = offsetof(fpm_model, xb) + sizeof(xb_arrays);
    memset(m, 0, at);                     /* all but the work arrays, the derived arrays (dv) and
                                             the exact rung's arrays */
    memset((char *)m + end, 0, sizeof *m - end);
    fpm_start_values(&m->v);
    m->t0 = start_time;
}

static void relink(fpm_model *m)
{
    m->p.I3 = m->I3;
    m->p.I5 = m->I5;
    m->p.K = m->K;
    m->p.D = m->D;
    m->p.Kg = m->Kg;
    m->p.tip_slope = m->tip_slope;
    m->p.tip_defl = m->tip_defl;
    m->p.pts = m->dv.pts;
}

/* ------------------------------------------------------------------ parameter checks */
/* check_real of plant_fmu/params.py: low/high bounds, open or closed, +inf allowed or not. */
static int check_real(const fpm_logger *lg, const char *name, double v, int has_low, double low,
                      int low_open, int has_high, double high, int high_open, int allow_inf)
{
    int ok = !isnan(v) && (isfinite(v) || (allow_inf && v == INFINITY));
    if (has_low) ok = ok && (low_open ? v > low : v >= low);
    if (has_high) ok = ok && (high_open ? v < high : v <= high);
    if (!ok) {
        char lo[32], hi[32];
        if (has_low) snprintf(lo, sizeof lo, "%g", low); else strcpy(lo, "-inf");
        if (has_high) snprintf(hi, sizeof hi, "%g", high); else strcpy(hi, "inf");
        fpm_log(lg, FPM_ERROR, "bad parameter: %s = %.17g is out of range; allowed: %s%s, %s%s",
                name, v, low_open ? "(" : "[", lo, hi, high_open ? ")" : "]");
    }
    return ok;
}

static int check_int(const fpm_logger *lg, const char *name, double v, int low, int high,
                     const char *why)
{
    if (!(v >= low && v <= high)) {
        fpm_log(lg, FPM_ERROR, "bad parameter: %s = %.17g is out of range; allowed: integers "
                "%d..%d%s", name, v, low, high, why);
        return 0;
    }
    return 1;
}

/* The quantities derived from the positive parameters are finite and normal (neither overflow
 * nor underflow to 0); else a message naming the parameters they come from. */
static int derived_ok(const fpm_logger *lg, const fpm_model *m, double rhoA, double w,
                      double slam)
{
    const double *r = m->v.real;
    struct { const char *what, *from; double v; } q[4];
    int i, j;
    q[0].what = "the mass per length rhoA = rho EA / E"; q[0].from = "rho, EA, E"; q[0].v = rhoA;
    q[1].what = "the mode scale 1 / sqrt(rhoA L)"; q[1].from = "rho, EA, E, L"; q[1].v = w;
    q[2].what = "the stiffness scale EI / (rhoA L^4)"; q[2].from = "EI, rho, EA, E, L";
    q[2].v = slam;
    q[3].what = "the total mass m + rhoA L"; q[3].from = "m, rho, EA, E, L";
    q[3].v = r[VR_m] + rhoA * r[VR_L];
    for (i = 0; i < 4; i++)
        if (!(isfinite(q[i].v) && fabs(q[i].v) >= 2.2250738585072014e-308)) {
            fpm_log(lg, FPM_ERROR, "bad parameter: %s = %g %s (from %s: m = %g, L = %g, rho = %g, "
                    "EA = %g, EI = %g, E = %g)", q[i].what, q[i].v,
                    isfinite(q[i].v) ? "underflows" : "overflows", q[i].from, r[VR_m], r[VR_L],
                    r[VR_rho], r[VR_EA], r[VR_EI], r[VR_E]);
            return 0;
        }
    for (j = 0; j < m->n; j++)
        if (!(isfinite(m->K[j]) && isfinite(m->D[j]) && isfinite(m->I3[j]) && isfinite(m->I5[j])
              && isfinite(m->tip_defl[j]) && isfinite(m->tip_slope[j]))) {
            fpm_log(lg, FPM_ERROR, "bad parameter: the modal data of mode %d overflow (from L = %g, "
                    "EI = %g, rho = %g, EA = %g, E = %g, zeta = %g, g = %g)", j + 1, r[VR_L],
                    r[VR_EI], r[VR_rho], r[VR_EA], r[VR_E], r[VR_zeta], r[VR_g]);
            return 0;
        }
    return 1;
}

/* Every output at y_acc into out (energy included); 1 if all are finite, else 0 with the first
 * output that is not in *bad (when bad is not NULL). */
static int outputs_ok(fpm_model *m, const char **bad)
{
    static const char *NAMES[FP_OUT_ETA] = {"x_o", "x_dot", "phi_o", "omega_o", "phi",
                                            "tip_deflection", "energy"};
    double norm2 = 0.0;
    int i;
    if (m->exact) return xb_outputs_ok(m, bad);
    for (i = 0; i < m->nx; i++) norm2 += m->y_acc[i] * m->y_acc[i];
    if (!(norm2 <= STATE_NORM2_LIMIT)) {
        if (bad) *bad = "the state's norm";
        return 0;
    }
    fp_outputs(&m->p, m->y_acc, 1, m->out);
    m->out_fresh = m->energy_fresh = 1;
    for (i = 0; i < FP_OUT_ETA + m->n; i++)
        if (!isfinite(m->out[i])) {
            if (bad) *bad = i < FP_OUT_ETA ? NAMES[i] : "a modal coordinate";
            m->out_fresh = m->energy_fresh = 0;
            return 0;
        }
    return 1;
}

/* The stiffened rung's mass points into pts (P rows of s_p, m_p, N(s_p), G(s_p)), as beam.py's
 * _unit_points and mass_points make them: numpy's Gauss-Legendre rule of P = 4 max(n, 4) points
 * on the unit beam, the modes' Hermite interpolants there, G(s) = int_0^s N'^T N' ds by 3-point
 * Gauss on each element before s and on the part of its own; then s scaled by L, the masses by
 * rhoA L, N by w and G by w^2 / L. Returns P. */
static void sf_hermite(double t, double le, double *Nh, double *dN)
{
    Nh[0] = 1 - 3 * t * t + 2 * t * t * t;
    Nh[1] = le * (t - 2 * t * t + t * t * t);
    Nh[2] = 3 * t * t - 2 * t * t * t;
    Nh[3] = le * (t * t * t - t * t);
    dN[0] = (-6 * t + 6 * t * t) / le;
    dN[1] = 1 - 4 * t + 3 * t * t;
    dN[2] = (6 * t - 6 * t * t) / le;
    dN[3] = -2 * t + 3 * t * t;
}

/* The element e's dof d (0..3) of mode j: the root's two dofs are 0. */
static double sf_dof(const double *modes, int e, int d, int j)
{
    const int row = 2 * e + d - 2;
    return row < 0 ? 0.0 : modes[(long)row * NMAX + j];
}

/* d/ds of the modes (n) at t of element e. */
static void sf_slopes(const double *modes, int e, double t, double le, int n, double *out)
{
    double Nh[4], dN[4];
    int j, d;
    sf_hermite(t, le, Nh, dN);
    for (j = 0; j < n; j++) {
        out[j] = 0.0;
        for (d = 0; d < 4; d++) out[j] += dN[d] * sf_dof(modes, e, d, j);
    }
}

/* acc += sum_q weight_q (N'_q)^T N'_q over the 3-point rule on [s_e, s_e + t le]. */
static void sf_accumulate(const double *modes, int e, double t, double le, int n, double *acc)
{
    double dw[NMAX];
    int q, i, j;
    for (q = 0; q < 3; q++) {
        const double wq = 0.5 * fpm_gauss3_w[q] * t * le;
        sf_slopes(modes, e, 0.5 * (fpm_gauss3_x[q] + 1.0) * t, le, n, dw);
        for (i = 0; i < n; i++)
            for (j = 0; j < n; j++) acc[i * n + j] += dw[i] * wq * dw[j];
    }
}

static int sf_points(double *pts, int ne, int n, double L, double rhoA, double w)
{
    const double *modes = fpm_unit_modes + FPM_MODES_AT(ne);
    const int P = 4 * (n > 4 ? n : 4), width = 2 + n + n * n, set = P / 4 - 4;
    const double le = 1.0 / ne, sG = w * w / L;
    double acc[NMAX * NMAX], G[NMAX * NMAX], Nh[4], dN[4];
    int k, e_acc = 0, i, j, d;
    for (i = 0; i < n * n; i++) acc[i] = 0.0;   /* G at node e_acc */
    for (k = 0; k < P; k++) {
        const double x = 0.5 * (fpm_gauss_x[set][k] + 1.0), wt = 0.5 * fpm_gauss_w[set][k];
        double *row = pts + (long)k * width;
        int e = (int)(x * ne);
        double t;
        if (e > ne - 1) e = ne - 1;
        while (e_acc < e) sf_accumulate(modes, e_acc++, 1.0, le, n, acc);
        t = x * ne - e;
        sf_hermite(t, le, Nh, dN);
        row[0] = x * L;
        row[1] = wt * (rhoA * L);
        for (j = 0; j < n; j++) {
            double v = 0.0;
            for (d = 0; d < 4; d++) v += Nh[d] * sf_dof(modes, e, d, j);
            row[2 + j] = v * w;
        }
        memcpy(G, acc, sizeof(double) * n * n);
        sf_accumulate(modes, e, t, le, n, G);
        for (i = 0; i < n * n; i++) row[2 + n + i] = G[i] * sG;
    }
    return P;
}

/* Build the plant and the stepper from the parameters (fmu.py's _prepare). */
static int prepare(fpm_model *m, const fpm_logger *lg)
{
    m->od_valid = 0;
    const double *r = m->v.real;
    double L = r[VR_L], EI = r[VR_EI], rho = r[VR_rho], EA = r[VR_EA], E = r[VR_E];
    double g = r[VR_g], zeta = r[VR_zeta], rhoA, w, sI3, sI5, slam, sslope, sKg;
    int n, ne, j, i, stiffened, kv;
    const char *fid = m->v.string[VR_fidelity], *integ = m->v.string[VR_integrator];
    const char *law = m->v.string[VR_damping];
    static const char *REAL_PARAMS[] = {"m", "L", "rho", "EA", "EI", "E"};
    static const unsigned REAL_VRS[] = {VR_m, VR_L, VR_rho, VR_EA, VR_EI, VR_E};
    m->ready = 0;
    for (i = 0; i < 6; i++)
        if (!check_real(lg, REAL_PARAMS[i], r[REAL_VRS[i]], 1, POSITIVE_MIN, 0, 1, 1e15, 0, 0))
            return 0;
    if (!check_real(lg, "zeta", zeta, 1, 0.0, 0, 1, 1.0, 1, 0)) return 0;
    kv = strcmp(law, "kelvin-voigt") == 0;      /* the damping law (plant_fmu/params.py) */
    m->xb_kv = kv;
    if (!kv && strcmp(law, "modal") != 0) {
        fpm_log(lg, FPM_ERROR, "bad parameter: damping = '%s' is not allowed; allowed: modal, "
                "kelvin-voigt", law);
        return 0;
    }
    if (!check_real(lg, "g", g, 1, 0.0, 0, 1, 1e3, 0, 0)) return 0;
    if (!check_int(lg, "n_elements", r[VR_n_elements], 1, FPM_NE_MAX,
                   " (the native FMU carries the modes of these meshes; the pythonfmu "
                   "FlexiblePendulum takes up to 400)")) return 0;
    ne = (int)r[VR_n_elements];
    if (!check_int(lg, "n_modes", r[VR_n_modes], 0, ne < NMAX ? ne : NMAX,
                   " (at most n_elements, and at most the modes the native FMU carries)"))
        return 0;
    n = (int)r[VR_n_modes];
    for (i = 0; i < FPM_N_RUNGS && strcmp(fid, fpm_rungs[i]) != 0; i++) {}
    if (i == FPM_N_RUNGS) {                    /* one FMU per rung family (fpm_vars.h) */
        fpm_log(lg, FPM_ERROR, "bad parameter: fidelity = '%s' is not a rung of %s; the native "
                "plant FMUs and their rungs: %s", fid, fpm_model_name, FPM_RUNG_FMUS);
        return 0;
    }
    m->exact = strcmp(fid, "exact") == 0;   /* the exact rung (xb_prepare): checked and */
    if (m->exact) fid = "nonlinear";        /* prepared as the nonlinear rung, then its own */
    stiffened = strcmp(fid, "stiffened") == 0;  /* the nonlinear rung with the preload and */
    if (stiffened) fid = "nonlinear";           /* the foreshortening's mass points */
    if (strcmp(fid, "nonlinear") != 0 && strcmp(fid, "linear") != 0) {
        fpm_log(lg, FPM_ERROR, "bad parameter: fidelity = '%s' is not allowed; allowed: "
                "nonlinear, linear, stiffened, exact", fid);
        return 0;
    }
    m->method = -1;
    for (i = 0; i < N_METHODS; i++)
        if (strcmp(integ, METHODS[i]) == 0) m->method = i;
    if (m->method < 0) {
        fpm_log(lg, FPM_ERROR, "bad parameter: integrator = '%s' is not supported by the native "
                "FlexiblePendulum; supported: dopri5, euler, exponential, rk4, "
                "symplectic_euler (radau and genalpha: the pythonfmu FMU)", integ);
        return 0;
    }
    if (m->method == M_EXPONENTIAL && strcmp(fid, "linear") != 0) {
        fpm_log(lg, FPM_ERROR, "bad parameter: integrator = 'exponential' integrates the plant "
                "linearised at the upright rest state: it needs fidelity = 'linear'");
        return 0;
    }
    if (!check_real(lg, "step", r[VR_step], 1, 0.0, 1, 1, INFINITY, 1, 0)) return 0;
    if (!check_real(lg, "rtol", r[VR_rtol], 1, 0.0, 1, 1, 1.0, 0, 0)) return 0;
    if (!check_real(lg, "atol", r[VR_atol], 1, 0.0, 1, 1, INFINITY, 1, 0)) return 0;
    if (!check_real(lg, "phi_limit", r[VR_phi_limit], 1, 0.0, 1, 0, 0.0, 0, 1)) return 0;
    if (!check_real(lg, "energy_limit", r[VR_energy_limit], 1, 0.0, 1, 0, 0.0, 0, 1)) return 0;
    if (!check_real(lg, "phi0", r[VR_phi0], 0, 0, 0, 0, 0, 0, 0)) return 0;
    if (!check_real(lg, "x0", r[VR_x0], 0, 0, 0, 0, 0, 0, 0)) return 0;
    if (!check_real(lg, "phi_dot0", r[VR_phi_dot0], 0, 0, 0, 0, 0, 0, 0)) return 0;
    if (!check_real(lg, "x_dot0", r[VR_x_dot0], 0, 0, 0, 0, 0, 0, 0)) return 0;

    /* the modal data: the unit beam's, scaled (beam.py: Scales.of, beam_model) */
    rhoA = rho * EA / E;
    w = 1.0 / sqrt(rhoA * L);
    sI3 = (rhoA * L) * w;
    sI5 = sI3 * L;
    slam = EI / (rhoA * ((L * L) * (L * L)));
    sslope = w / L;
    sKg = g / L;
    m->n = n;
    m->nq = n + 2;
    m->nx = 2 * (n + 2);
    for (j = 0; j < n; j++) {
        double K = fpm_unit_lam[ne - 1][j] * slam, omega = sqrt(K);
        m->K[j] = K;
        /* beam.py's damping_diagonal: modal 2 zeta omega_j; Kelvin-Voigt beta K_j with beta =
         * 2 zeta / omega_1, on the material stiffness alone (not on Kg) */
        m->D[j] = kv ? 2.0 * zeta / sqrt(fpm_unit_lam[ne - 1][0] * slam) * K
                     : 2.0 * zeta * omega;
        m->I3[j] = fpm_unit_I3[ne - 1][j] * sI3;
        m->I5[j] = fpm_unit_I5[ne - 1][j] * sI5;
        m->tip_defl[j] = fpm_unit_tip_defl[ne - 1][j] * w;
        m->tip_slope[j] = fpm_unit_tip_slope[ne - 1][j] * sslope;
        for (i = 0; i < n; i++)
            m->Kg[j * n + i] = r[VR_gravity_preload] != 0.0 || stiffened
                ? fpm_unit_Kg[ne - 1][j * NMAX + i] * sKg : 0.0;
    }
    if (!derived_ok(lg, m, rhoA, w, slam)) return 0;
    memset(&m->p, 0, sizeof m->p);
    m->p.n = n;
    m->p.linear = strcmp(fid, "linear") == 0;
    m->p.preload = (r[VR_gravity_preload] != 0.0 || stiffened) && n > 0;
    if (stiffened) {                            /* always with the self-weight (dynamics.py) */
        m->p.stiffened = 1;
        m->p.npts = sf_points(m->dv.pts, ne, n, L, rhoA, w);
    }
    m->p.I0 = r[VR_m] + rhoA * L;
    m->p.I1 = rhoA * (L * L) / 2;
    m->p.I2 = rhoA * (L * L * L) / 3;
    m->p.g = g;
    relink(m);
    if (fp_plant_prepare(&m->p) != FP_OK) {
        fpm_log(lg, FPM_ERROR, "bad parameter: the plant's invariants are not finite");
        return 0;
    }
    m->h = r[VR_step];
    m->rtol = r[VR_rtol];
    m->atol = r[VR_atol];
    m->phi_limit = r[VR_phi_limit];
    m->energy_limit = r[VR_energy_limit];

    /* the stepper at t0 with the undeformed beam and a held input 0 (make_stepper) */
    memset(&m->s, 0, sizeof m->s);
    m->s.t = m->s.t_base = m->s.tu = m->t0;
    m->s.y[0] = r[VR_x0];
    m->s.y[1] = r[VR_phi0];
    m->s.y[m->nq] = r[VR_x_dot0];
    m->s.y[m->nq + 1] = r[VR_phi_dot0];
    m->s.h_abs = m->h;                    /* min(h, max_step = inf) */
    if (m->method == M_DOPRI5) fp_rhs(&m->p, m->s.y, 0.0, m->s.f);
    if (m->method == M_EXPONENTIAL) {     /* A and B of the linear plant, by columns */
        double x[NXMAX], dx[NXMAX];
        int nx = m->nx;
        memset(x, 0, sizeof x);
        for (j = 0; j < nx; j++) {
            x[j] = 1.0;
            fp_rhs(&m->p, x, 0.0, dx);
            x[j] = 0.0;
            for (i = 0; i < nx; i++) m->dv.A[i * nx + j] = dx[i];
        }
        fp_rhs(&m->p, x, 1.0, m->dv.B);
        m->dv.ex[0].h = m->dv.ex[1].h = -1.0;
    }
    if (m->exact && !xb_prepare(m, lg)) return 0;
    memcpy(m->y_acc, m->s.y, sizeof m->y_acc);
    m->failed = 0;
    m->stepped = 0;
    m->error[0] = '\0';
    if (!outputs_ok(m, NULL)) {                /* plant_fmu/fmu.py's _build */
        fpm_log(lg, FPM_ERROR, "bad parameter: the initial state (phi0 = %.17g, x0 = %.17g, "
                "phi_dot0 = %.17g, x_dot0 = %.17g) is too large: its energy or outputs would not "
                "be finite (|state| must stay below 1e100)", r[VR_phi0], r[VR_x0],
                r[VR_phi_dot0], r[VR_x_dot0]);
        return 0;
    }
    m->ready = 1;
    return 1;
}

/* The exponential method's discretisations depend on the linear plant (A, B) and the step
 * only. */
void fpm_model_keep(fpm_model *m, const fpm_model *from)
{
    const size_t nx = (size_t)m->nx;
    if (m->ready && from->ready && m->method == M_EXPONENTIAL && from->method == M_EXPONENTIAL &&
        from->nx == m->nx && memcmp(m->dv.A, from->dv.A, nx * nx * sizeof m->dv.A[0]) == 0 &&
        memcmp(m->dv.B, from->dv.B, nx * sizeof m->dv.B[0]) == 0) {
        memcpy(m->dv.ex, from->dv.ex, sizeof m->dv.ex);
        m->ex_next = from->ex_next;
    }
}

int fpm_model_init(fpm_model *m, const fpm_logger *lg)
{
    m->initialized = prepare(m, lg);
    return m->initialized ? FPM_OK : FPM_ERROR;
}


/* ------------------------------------------------------------------ stepping */
/* The exact discretisation of the linear plant over h (exponential.py's zoh_discretize). */
static expo *discretisation(fpm_model *m, double h)
{
    int nx = m->nx, na = nx + 1, i, j;
    expo *e;
    if (m->dv.ex[0].h == h) return &m->dv.ex[0];
    if (m->dv.ex[1].h == h) return &m->dv.ex[1];
    e = &m->dv.ex[m->ex_next];
    memset(m->scr.aug, 0, sizeof m->scr.aug);
    for (i = 0; i < nx; i++) {
        for (j = 0; j < nx; j++) m->scr.aug[i * na + j] = m->dv.A[i * nx + j] * h;
        m->scr.aug[i * na + nx] = m->dv.B[i] * h;
    }
    if (fpf_expm(na, m->scr.aug, m->scr.E, m->scr.ework) != FPF_OK) return NULL;
    for (i = 0; i < nx; i++) {
        for (j = 0; j < nx; j++) e->Phi[i * nx + j] = m->scr.E[i * na + j];
        e->Gam[i] = m->scr.E[i * na + nx];
    }
    e->h = h;
    m->ex_next = 1 - m->ex_next;
    return e;
}

static int finite_state(const double *y, int nx)
{
    double s = 0.0;
    int i;
    for (i = 0; i < nx; i++) s += y[i] * y[i];
    return s < INFINITY;
}

/* n substeps of h from the stepper's time (base.py's _full_substeps): 1, 0 with the message on
 * failure, or -1 when the exact rung's work budget ran out (xb_substeps). */
static int substeps(fpm_model *m, double h, long n, char *why)
{
    stepper *s = &m->s;
    long done = 0;
    if (n < 1) return 1;
    if (m->exact) return xb_substeps(m, h, n, why);
    if (m->method == M_EXPONENTIAL) {
        int nx = m->nx, i, j;
        long q;
        expo *e = discretisation(m, h);
        double y[NXMAX];
        if (e == NULL) {
            snprintf(why, FPM_MSG_MAX, "the matrix exponential over h = %.17g overflows", h);
            return 0;
        }
        for (q = 0; q < n; q++) {
            for (i = 0; i < nx; i++) {
                double a = 0.0;
                for (j = 0; j < nx; j++) a += e->Phi[i * nx + j] * s->y[j];
                y[i] = a + e->Gam[i] * s->u;
            }
            if (!finite_state(y, nx)) break;
            memcpy(s->y, y, sizeof(double) * nx);
            s->k += 1;
            s->t = s->t_base + s->k * h;
            done++;
        }
    } else {
        fp_input in;
        int rc;
        in.u0 = s->u;
        in.du = s->du;
        in.d2u = s->d2u;
        in.tu = s->tu;
        if (m->method == M_SYMPLECTIC)
            rc = fp_fixed_steps(&m->p, FP_SYMPLECTIC_EULER, NULL, &in, s->t, h, n, s->y,
                                m->scr.work, &done);
        else
            rc = fp_fixed_steps(&m->p, -1, fp_builtin_tableau(m->method == M_RK4 ? FP_RK4 : FP_EULER),
                                &in, s->t, h, n, s->y, m->scr.work, &done);
        if (rc == FP_BADARG) {
            snprintf(why, FPM_MSG_MAX, "bad substep h = %.17g", h);
            return 0;
        }
        s->k += done;
        s->t = s->t_base + s->k * h;
    }
    if (done < n) {
        snprintf(why, FPM_MSG_MAX, "non-finite state after the substep from t = %.17g (h = %.17g)",
                 s->t, h);
        return 0;
    }
    return 1;
}

/* One substep on the grid, shortened to land on t_bound (base.py's _fixed_substep). */
static int short_substep(fpm_model *m, double t_bound, char *why)
{
    stepper *s = &m->s;
    double h = m->h, t_grid = s->t_base + (s->k + 1) * h, hs, t_new;
    double snap = SNAP * h + 4 * EPS * fabs(t_grid);
    int rebase = 0;
    long k = s->k + 1;
    if (t_grid < t_bound - snap) {
        t_new = t_grid;
        hs = h;
    } else if (t_grid <= t_bound + snap) {
        t_new = t_bound;
        hs = h;
    } else {
        t_new = t_bound;
        hs = t_bound - s->t;
        rebase = 1;
    }
    {
        double t_base = s->t_base;
        long k0 = s->k;
        s->t_base = s->t;                 /* one substep of hs from s->t */
        s->k = 0;
        int rc = substeps(m, hs, 1, why);
        if (rc != 1) {
            s->t_base = t_base;
            s->k = k0;
            return rc;
        }
        s->t_base = t_base;
        s->k = k0;
    }
    s->t = t_new;
    if (rebase) {
        s->t_base = t_bound;
        s->k = 0;
    } else {
        s->k = k;
    }
    return 1;
}

/* The fixed-step advance to t_end (base.py's _advance_fixed): 1, or 0 with why on failure, or
 * -1 if it would take more than FPM_MAX_SUBSTEPS substeps (nothing done) or, on the exact rung,
 * more than FPM_MAX_EXACT_WORK element-iterations (the caller restores the state). */
static int advance_fixed(fpm_model *m, double t_end, char *why)
{
    stepper *s = &m->s;
    double h = m->h, n_grid = (t_end - s->t_base) / h, n_round = nearbyint(n_grid), n_full;
    int short_ = 0;
    /* the count in floating point, checked against the cap before it becomes an integer (a
     * count of 2^63 or more, or not finite, has no long: the cast would be undefined) */
    if (fabs(n_grid - n_round) <= SNAP + 4 * EPS * fabs(t_end) / h) {
        n_full = n_round - (double)s->k;
    } else {
        n_full = floor(n_grid) - (double)s->k;
        short_ = 1;
    }
    if (!(n_full + short_ <= (double)FPM_MAX_SUBSTEPS)) {
        snprintf(why, FPM_MSG_MAX, "the step to t = %.17g needs %.17g substeps of %.17g s, more "
                 "than the cap of %ld per doStep: take shorter communication steps or a larger "
                 "plant step", t_end, n_full + short_, h, FPM_MAX_SUBSTEPS);
        return -1;
    }
    if (m->exact && !((n_full + short_) * m->xb_p.ne <= (double)FPM_MAX_EXACT_WORK)) {
        snprintf(why, FPM_MSG_MAX, "the step to t = %.17g needs %.17g substeps of %.17g s on %d "
                 "elements, at least %.17g element-iterations, more than the exact rung's budget "
                 "of %ld per doStep: take shorter communication steps, a larger plant step or "
                 "fewer elements", t_end, n_full + short_, h, m->xb_p.ne,
                 (n_full + short_) * m->xb_p.ne, FPM_MAX_EXACT_WORK);
        return -1;
    }
    {
        int rc = substeps(m, h, (long)n_full, why);
        if (rc != 1) return rc;
    }
    if (!short_) {
        s->t = t_end;
        return 1;
    }
    return short_substep(m, t_end, why);
}

/* The adaptive advance (rk.py's _compiled_adaptive): 1, 0 with why, or -1 at the cap. */
static int advance_dopri(fpm_model *m, double t_end, char *why)
{
    stepper *s = &m->s;
    fp_adaptive a;
    fp_input in;
    double t = s->t;
    int rc;
    memset(&a, 0, sizeof a);
    a.rtol = m->rtol;
    a.atol = &m->atol;
    a.n_atol = 1;
    a.max_step = INFINITY;
    a.min_step = 0.0;
    a.max_steps = FPM_MAX_SUBSTEPS;
    a.h_abs = s->h_abs;
    in.u0 = s->u;
    in.du = s->du;
    in.d2u = s->d2u;
    in.tu = s->tu;
    rc = fp_dopri_advance(&m->p, fp_builtin_tableau(FP_DOPRI5), &in, &t, t_end, s->y, s->f, &a,
                          m->scr.work);
    s->t = t;
    s->h_abs = a.h_abs;
    if (rc == FP_OK) return 1;
    if (rc == FP_CAP) {
        snprintf(why, FPM_MSG_MAX, "dopri5 reached the cap of %ld accepted steps per doStep at "
                 "t = %.17g before t = %.17g (rtol = %g, atol = %g): take shorter communication "
                 "steps or looser tolerances", FPM_MAX_SUBSTEPS, t, t_end, m->rtol, m->atol);
        return -1;
    }
    if (rc == FP_UNDERFLOW) {
        snprintf(why, FPM_MSG_MAX, "step size underflow at t = %.17g: h = %.17g is below the "
                 "minimum %.17g", t, a.fail_h, a.fail_min_step);
        return 0;
    }
    snprintf(why, FPM_MSG_MAX, "bad arguments to the adaptive loop (code %d)", rc);
    return 0;
}

/* The input over the step (fmu.py's do_step, base.py's set_input and _prepare_input). */
static void set_input(fpm_model *m, double t, double h)
{
    stepper *s = &m->s;
    double u = m->v.real[VR_F_c], du = m->dF, d2u = m->d2F;
    int poly;
    if (!(du != 0.0 || d2u != 0.0)) {
        s->u = u;
        s->du = s->d2u = 0.0;
    } else if (m->method != M_EXPONENTIAL) {
        s->u = u;
        s->du = du;
        s->d2u = d2u;
        s->tu = t;
    } else {                                  /* a held-input method: the step average */
        s->u = u + h * (0.5 * du + h * d2u / 6.0);
        s->du = s->d2u = 0.0;
    }
    poly = s->du != 0.0 || s->d2u != 0.0;
    if (poly != s->prev_poly || s->prev[0] != s->u ||
        (poly && (s->prev[1] != s->du || s->prev[2] != s->d2u || s->prev[3] != s->tu))) {
        if (m->method == M_DOPRI5) {          /* f = f(t, y, u(t)) for the new input */
            double ut = s->u;
            if (poly) {
                double q = s->t - s->tu;
                ut = s->u + q * (s->du + 0.5 * q * s->d2u);
            }
            fp_rhs(&m->p, s->y, ut, s->f);
        }
        s->prev_poly = poly;
        s->prev[0] = s->u;
        s->prev[1] = s->du;
        s->prev[2] = s->d2u;
        s->prev[3] = s->tu;
    }
}

/* dst = a b (truncated to n bytes with its 0). */
static void join(char *dst, size_t n, const char *a, const char *b)
{
    size_t la = strlen(a), lb = strlen(b);
    if (la > n - 1) la = n - 1;
    if (lb > n - 1 - la) lb = n - 1 - la;
    memmove(dst, a, la);
    memcpy(dst + la, b, lb);
    dst[la + lb] = '\0';
}

static int refuse(fpm_model *m, const fpm_logger *lg, int status, const char *what)
{
    fpm_log(lg, status, "%s", what);
    (void)m;
    return status;
}

static int diverged(fpm_model *m, const fpm_logger *lg, const stepper *saved, const char *why)
{
    m->s = *saved;                            /* the state at the start of the step */
    join(m->error, sizeof m->error, why, "; restore a saved FMU state to continue");
    m->failed = 1;
    return refuse(m, lg, FPM_DISCARD, m->error);
}

int fpm_model_step(fpm_model *m, const fpm_logger *lg, double t, double h)
{
    char why[FPM_MSG_MAX];
    double u = m->v.real[VR_F_c], t_end = t + h, norm2 = 0.0, phi;
    stepper saved;
    int i, rc;
    if (!m->initialized || m->failed) {
        char msg[FPM_MSG_MAX];
        join(msg, sizeof msg, "FlexiblePendulum cannot step: ",
             m->failed ? m->error : "it was not initialised");
        return refuse(m, lg, m->failed ? FPM_DISCARD : FPM_ERROR, msg);
    }
    if (!isfinite(u + m->dF + m->d2F)) {
        fpm_log(lg, FPM_DISCARD, "non-finite input F_c = %.17g (derivatives %.17g, %.17g) at t = "
                "%.17g; step rejected, state unchanged", u, m->dF, m->d2F, t);
        return FPM_DISCARD;
    }
    if (m->exact) return xb_step(m, lg, t, h);
    saved = m->s;
    set_input(m, t, h);
    if (!(t_end <= m->s.t)) {
        rc = m->method == M_DOPRI5 ? advance_dopri(m, t_end, why) : advance_fixed(m, t_end, why);
        if (rc < 0) {                         /* the cap: nothing accepted, retry allowed */
            m->s = saved;
            fpm_log(lg, FPM_DISCARD, "%s; step rejected, state unchanged", why);
            return FPM_DISCARD;
        }
        if (rc == 0) {
            char head[160], msg[FPM_MSG_MAX];
            snprintf(head, sizeof head, "integrator '%s' failed between t = %.17g and %.17g: ",
                     METHODS[m->method], t, t_end);
            join(msg, sizeof msg - 64, head, why);
            return diverged(m, lg, &saved, msg);
        }
    }
    /* divergence checks (fmu.py's _check) */
    for (i = 0; i < m->nx; i++) norm2 += m->s.y[i] * m->s.y[i];
    if (!(norm2 <= STATE_NORM2_LIMIT)) {
        snprintf(why, sizeof why, "divergence at t = %.17g: the state's norm %.17g exceeds 1e100 "
                 "(numerical blow-up)", t_end, sqrt(norm2));
        return diverged(m, lg, &saved, why);
    }
    phi = m->s.y[1];
    if (!(fabs(phi) <= m->phi_limit)) {
        snprintf(why, sizeof why, "divergence at t = %.17g: |phi| = %.17g exceeds phi_limit = "
                 "%.17g", t_end, fabs(phi), m->phi_limit);
        return diverged(m, lg, &saved, why);
    }
    {   /* the outputs of the new state, each finite, or the step is refused */
        const char *bad = "";
        double y_prev[NXMAX];
        memcpy(y_prev, m->y_acc, sizeof y_prev);
        memcpy(m->y_acc, m->s.y, sizeof m->y_acc);
        if (!outputs_ok(m, &bad)) {
            memcpy(m->y_acc, y_prev, sizeof y_prev);
            snprintf(why, sizeof why, "divergence at t = %.17g: the output %s would not be "
                     "finite", t_end, bad);
            return diverged(m, lg, &saved, why);
        }
        if (!(fabs(m->out[FP_OUT_ENERGY]) <= m->energy_limit)) {
            double energy = m->out[FP_OUT_ENERGY];
            memcpy(m->y_acc, y_prev, sizeof y_prev);
            m->out_fresh = m->energy_fresh = 0;
            snprintf(why, sizeof why, "divergence at t = %.17g: |energy| = %.17g exceeds "
                     "energy_limit = %.17g", t_end, fabs(energy), m->energy_limit);
            return diverged(m, lg, &saved, why);
        }
    }
    m->stepped = 1;
    return FPM_OK;
}

/* ------------------------------------------------------------------ outputs and inputs */
int fpm_model_get_output(fpm_model *m, const fpm_logger *lg, unsigned vr, double *value)
{
    int j, n_eta;
    if (!m->initialized && !prepare(m, lg)) {   /* read before initialisation: from the
                                                    parameters as they are now */
        fpm_log(lg, FPM_ERROR, "the outputs cannot be computed: a parameter is bad (above)");
        return FPM_ERROR;
    }
    if (m->exact) {                           /* outputs and energy with each state */
        if (!m->out_fresh) xb_outputs_ok(m, NULL);
        n_eta = FPM_N_ETA;                    /* eta_1 = tip / N_1(L), the rest 0 */
    } else {
        if (!m->out_fresh) {
            double energy = m->out[FP_OUT_ENERGY];
            fp_outputs(&m->p, m->y_acc, 0, m->out);
            m->out[FP_OUT_ENERGY] = energy;
            m->out_fresh = 1;
        }
        if (vr == VR_energy && !m->energy_fresh) {
            m->out[FP_OUT_ENERGY] = fp_energy(&m->p, m->y_acc);
            m->energy_fresh = 1;
        }
        n_eta = m->n;                         /* the modes beyond n_modes: 0 */
    }
    switch (vr) {
    case VR_x_o: *value = m->out[FP_OUT_X]; break;
    case VR_x_dot: *value = m->out[FP_OUT_XDOT]; break;
    case VR_phi_o: *value = m->out[FP_OUT_PHI_O]; break;
    case VR_omega_o: *value = m->out[FP_OUT_OMEGA_O]; break;
    case VR_phi: *value = m->out[FP_OUT_PHI]; break;
    case VR_tip_deflection: *value = n_eta ? m->out[FP_OUT_TIP] : 0.0; break;
    case VR_energy: *value = m->out[FP_OUT_ENERGY]; break;
    default:
        for (j = 0; j < FPM_N_ETA; j++)
            if (vr == fpm_eta_vrs[j]) {
                *value = j < n_eta ? m->out[FP_OUT_ETA + j] : 0.0;
                break;
            }
        if (j == FPM_N_ETA) {
            fpm_log(lg, FPM_ERROR, "value reference %u is not an output", vr);
            return FPM_ERROR;
        }
    }
    if (!isfinite(*value)) {                  /* never: steps and initialisation refuse it */
        fpm_log(lg, FPM_ERROR, "the output %s = %g is not finite at t = %.17g", fpm_vars[vr].name,
                *value, fpm_model_time(m));
        return FPM_ERROR;
    }
    return FPM_OK;
}

int fpm_model_set_input_derivative(fpm_model *m, const fpm_logger *lg, unsigned vr, int order,
                                   double value)
{
    if (vr != VR_F_c || (order != 1 && order != 2)) {
        fpm_log(lg, FPM_ERROR, "fmi2SetRealInputDerivatives: %s takes derivatives of order 1 and "
                "2 of F_c only (got order %d of value reference %u)", fpm_model_name, order, vr);
        return FPM_ERROR;
    }
    if (order == 1) m->dF = value;
    else m->d2F = value;
    return FPM_OK;
}

/* ================================================================== Model Exchange (issue 24)
 * The states [x, phi, eta_1..eta_8, x_dot, phi_dot, eta_dot_1..eta_dot_8] (FPM_NX = 2 (8 + 2):
 * the modes of the largest n_modes; the kernel's state, nx = 2 (n + 2), holds the first n modes,
 * the states of the others stay 0 with derivative 0). Model Exchange keeps its state where
 * co-simulation keeps it: the stepper's time s.t and state s.y (what FMU states save and restore,
 * with the checks of a restore), mirrored in y_acc (what the outputs read; out_fresh and
 * energy_fresh cleared whenever it changes). The derivative is the kernel's right-hand side
 * fp_rhs at the input F_c set now (no input derivatives in Model Exchange). Event indicators:
 * the divergence bounds as smooth, finite functions, 1 - (phi/phi_limit)^2 and
 * 1 - (energy/energy_limit)^2, which cross 0 where a co-simulation step would be refused; at
 * that event the FMU asks the importer to terminate. */
#define ME_NQ (FPM_N_ETA + 2)
#if FPM_NX != 2 * ME_NQ || FPM_N_ETA < FPM_N_MODES_MAX
#error "the Model-Exchange states of fpm_vars.h are not [q of 8 modes, their rates]"
#endif
#define ME_BOUND_TOL 1e-8         /* an indicator at most this is at its bound (the importer's
                                     root finder stops within its tolerance of the crossing) */
#define ME_RATIO_MAX 1e150        /* |phi|/phi_limit and |E|/energy_limit clamped: finite */

size_t fpm_model_nz(void) { return FPM_NZ; }

int fpm_model_me_init(fpm_model *m, const fpm_logger *lg)
{
    if (m->exact) return xb_refuse(m, lg, "Model Exchange");
    if (2 * (m->n + 2) > FPM_NX) {
        fpm_log(lg, FPM_ERROR, "bad parameter: n_modes = %d: Model Exchange declares the states of "
                "at most %d modes", m->n, FPM_NX / 2 - 2);
        return FPM_ERROR;
    }
    return FPM_OK;
}

/* A new state or time: the outputs follow it. */
static void me_moved(fpm_model *m)
{
    memcpy(m->y_acc, m->s.y, sizeof m->y_acc);
    m->out_fresh = m->energy_fresh = 0;
}

int fpm_model_set_time(fpm_model *m, const fpm_logger *lg, double t)
{
    if (!(t >= m->t0)) {
        fpm_log(lg, FPM_ERROR, "time = %.17g is before the start time %.17g", t, m->t0);
        return FPM_ERROR;
    }
    m->s.t = t;
    m->s.t_base = m->t0;
    m->s.k = 0;
    return FPM_OK;
}

void fpm_model_get_states(const fpm_model *m, double *x)
{
    int i, nq = m->nq;
    for (i = 0; i < FPM_NX; i++) x[i] = 0.0;
    for (i = 0; i < nq; i++) {
        x[i] = m->s.y[i];
        x[ME_NQ + i] = m->s.y[nq + i];
    }
}

int fpm_model_set_states(fpm_model *m, const fpm_logger *lg, const double *x)
{
    int i, nq = m->nq;
    (void)lg;
    for (i = 0; i < nq; i++) {               /* the states of modes beyond n_modes: not used */
        m->s.y[i] = x[i];
        m->s.y[nq + i] = x[ME_NQ + i];
    }
    me_moved(m);
    return FPM_OK;
}

/* The kernel's derivative at y_acc and F_c into dx (FPM_NX doubles). */
static int me_rhs(fpm_model *m, const fpm_logger *lg, double *dx)
{
    double d[NXMAX], u = m->v.real[VR_F_c];
    int i, nq = m->nq;
    if (!isfinite(u)) {
        fpm_log(lg, FPM_ERROR, "the input F_c = %g is not finite at t = %.17g", u, m->s.t);
        return FPM_ERROR;
    }
    fp_rhs(&m->p, m->y_acc, u, d);
    for (i = 0; i < FPM_NX; i++) dx[i] = 0.0;
    for (i = 0; i < nq; i++) {
        dx[i] = d[i];
        dx[ME_NQ + i] = d[nq + i];
    }
    for (i = 0; i < FPM_NX; i++)
        if (!isfinite(dx[i])) {
            fpm_log(lg, FPM_ERROR, "the derivative of state %d is not finite at t = %.17g (the "
                    "state or F_c = %g is too large)", i, m->s.t, u);
            return FPM_ERROR;
        }
    return FPM_OK;
}

int fpm_model_derivatives(fpm_model *m, const fpm_logger *lg, double *dx)
{
    if (m->exact) return xb_refuse(m, lg, "the state derivatives (Model Exchange)");
    return me_rhs(m, lg, dx);
}

static double positive_or_1(double v)
{
    return isfinite(v) && v > 0.0 ? v : 1.0;
}

/* x: L; phi: 1 rad; eta_j: 0.01 L / |N_j(L)| (a tip deflection of 1 % of L); x_dot: sqrt(g L)
 * and phi_dot: sqrt(g / L), the pendulum's scales (L/s and 1/s when g = 0); eta_dot_j: omega_j
 * times the nominal of eta_j; the states of modes beyond n_modes: 1. */
void fpm_model_nominals(const fpm_model *m, double *nominal)
{
    double L = m->v.real[VR_L], g = m->p.g;
    int j;
    for (j = 0; j < FPM_NX; j++) nominal[j] = 1.0;
    nominal[0] = positive_or_1(L);
    nominal[ME_NQ] = positive_or_1(g > 0.0 ? sqrt(g * L) : L);
    nominal[ME_NQ + 1] = positive_or_1(g > 0.0 ? sqrt(g / L) : 1.0);
    for (j = 0; j < m->n; j++) {
        double eta = positive_or_1(0.01 * L / fabs(m->tip_defl[j]));
        nominal[2 + j] = eta;
        nominal[ME_NQ + 2 + j] = positive_or_1(sqrt(m->K[j]) * eta);
    }
}

static double indicator(double v, double limit)
{
    double r = fabs(v) / limit;             /* limit > 0 (initialisation checks it) */
    if (!(r <= ME_RATIO_MAX)) r = ME_RATIO_MAX;
    return 1.0 - r * r;
}

static double me_energy(fpm_model *m)
{
    if (!m->energy_fresh) {
        m->out[FP_OUT_ENERGY] = fp_energy(&m->p, m->y_acc);
        m->energy_fresh = 1;
    }
    return m->out[FP_OUT_ENERGY];
}

int fpm_model_event_indicators(fpm_model *m, const fpm_logger *lg, double *z)
{
    double energy = me_energy(m);
    if (!isfinite(energy) || !isfinite(m->y_acc[1])) {
        fpm_log(lg, FPM_ERROR, "the event indicators are not finite at t = %.17g: phi = %g, "
                "energy = %g", m->s.t, m->y_acc[1], energy);
        return FPM_ERROR;
    }
    z[0] = indicator(m->y_acc[1], m->phi_limit);
    z[1] = indicator(energy, m->energy_limit);
    return FPM_OK;
}

int fpm_model_event_update(fpm_model *m, const fpm_logger *lg, int *terminate)
{
    double z[FPM_NZ];
    int rc = fpm_model_event_indicators(m, lg, z);
    if (rc != FPM_OK) return rc;
    if (z[0] <= ME_BOUND_TOL) {
        fpm_log(lg, FPM_WARNING, "divergence at t = %.17g: |phi| = %.17g reached phi_limit = "
                "%.17g; the simulation terminates (terminateSimulation)", m->s.t,
                fabs(m->y_acc[1]), m->phi_limit);
        *terminate = 1;
        return FPM_WARNING;
    }
    if (z[1] <= ME_BOUND_TOL) {
        fpm_log(lg, FPM_WARNING, "divergence at t = %.17g: |energy| = %.17g reached energy_limit "
                "= %.17g; the simulation terminates (terminateSimulation)", m->s.t,
                fabs(m->out[FP_OUT_ENERGY]), m->energy_limit);
        *terminate = 1;
        return FPM_WARNING;
    }
    return FPM_OK;
}

int fpm_model_get_local(fpm_model *m, const fpm_logger *lg, unsigned vr, double *value)
{
    const fpm_var *v = &fpm_vars[vr];
    double a[FPM_NX > FPM_NZ ? FPM_NX : FPM_NZ];
    int rc = FPM_OK;
    if (!m->initialized && !prepare(m, lg)) {
        fpm_log(lg, FPM_ERROR, "%s cannot be computed: a parameter is bad (above)", v->name);
        return FPM_ERROR;
    }
    if (m->exact) return xb_refuse(m, lg, v->name);
    if (v->state) {
        fpm_model_get_states(m, a);
        *value = a[v->state - 1];
    } else if (v->der) {
        rc = me_rhs(m, lg, a);
        *value = a[v->der - 1];
    } else if (v->indicator) {
        rc = fpm_model_event_indicators(m, lg, a);
        *value = a[v->indicator - 1];
    } else {
        fpm_log(lg, FPM_ERROR, "value reference %u is not a Model-Exchange local", vr);
        return FPM_ERROR;
    }
    return rc;
}
/* ================================================================== end of Model Exchange */

/* ------------------------------------------------------------------ FMU states */
int fpm_model_initialized(const fpm_model *m) { return m->initialized; }

void fpm_model_save(const fpm_model *m, fpm_writer *w)
{
    const stepper *s = &m->s;
    int i;
    fpm_put_f64(w, m->t0);
    fpm_put_f64(w, m->dF);
    fpm_put_f64(w, m->d2F);
    fpm_put_i32(w, m->initialized);
    if (!m->initialized) return;
    fpm_put_i32(w, m->failed);
    fpm_put_str(w, m->error);
    fpm_put_f64(w, s->t);
    fpm_put_f64(w, s->t_base);
    fpm_put_f64(w, (double)s->k);
    for (i = 0; i < m->nx; i++) fpm_put_f64(w, s->y[i]);
    for (i = 0; i < m->nx; i++) fpm_put_f64(w, s->f[i]);
    fpm_put_f64(w, s->h_abs);
    fpm_put_f64(w, s->u);
    fpm_put_f64(w, s->du);
    fpm_put_f64(w, s->d2u);
    fpm_put_f64(w, s->tu);
    fpm_put_i32(w, s->prev_poly);
    for (i = 0; i < 4; i++) fpm_put_f64(w, s->prev[i]);
    fpm_put_i32(w, m->stepped);
    if (m->exact)                             /* the exact rung's integrator state */
        for (i = 0; i < 4 * m->xb_p.nq; i++) fpm_put_f64(w, m->xb.s[i]);
}

/* The restore of a co-simulation state into the instance whose live model `live` is initialised
 * from the same parameters (every parameter of the table bitwise equal, strings equal, the same
 * t0): prepare() would pass the same checks and compute the same derived quantities bit for
 * bit, so they are copied instead (an implicit master restores a state several times a step,
 * and prepare is most of a restore's cost). 1 if they were: m is then as prepare() leaves it,
 * except the stepper, y_acc, the outputs and what a refusal leaves (failed, error, stepped),
 * which fpm_model_load's co-simulation path overwrites whole. Not for the exact rung (its
 * integrator's data change with its steps) nor Model Exchange (whose load leaves prepare's
 * outputs of the initial state in out). */
static int prepared_like(fpm_model *m, const fpm_model *live, const fpm_reader *r)
{
    int i;
    if (live == NULL || !live->initialized || !live->ready || live->exact ||
        r->interface != FPM_COSIMULATION || memcmp(&m->t0, &live->t0, sizeof m->t0) != 0)
        return 0;
    for (i = 0; i < FPM_MAX_VARS; i++) {
        const fpm_var *var = &fpm_vars[i];
        if (var->name == NULL || var->causality != FPM_PARAMETER) continue;
        if (var->type == FPM_STRING ? strcmp(m->v.string[i], live->v.string[i]) != 0
            : memcmp(&m->v.real[i], &live->v.real[i], sizeof m->v.real[i]) != 0)
            return 0;
    }
    /* what prepare() writes (m is fresh from fpm_model_reset, as live was when it was
     * prepared: the parts of the modal arrays beyond n are 0 in both; of dv, the parts that
     * prepare writes, which are all that is read) */
    m->xb_kv = live->xb_kv;
    m->exact = 0;
    m->method = live->method;
    m->n = live->n;
    m->nq = live->nq;
    m->nx = live->nx;
    memcpy(m->K, live->K, sizeof m->K);
    memcpy(m->D, live->D, sizeof m->D);
    memcpy(m->I3, live->I3, sizeof m->I3);
    memcpy(m->I5, live->I5, sizeof m->I5);
    memcpy(m->tip_defl, live->tip_defl, sizeof m->tip_defl);
    memcpy(m->tip_slope, live->tip_slope, sizeof m->tip_slope);
    memcpy(m->Kg, live->Kg, sizeof m->Kg);
    m->p = live->p;
    if (m->p.stiffened)                         /* the rows sf_points wrote */
        memcpy(m->dv.pts, live->dv.pts, sizeof(double) * (size_t)m->p.npts *
               (size_t)(2 + m->n + m->n * m->n));
    relink(m);
    m->h = live->h;
    m->rtol = live->rtol;
    m->atol = live->atol;
    m->phi_limit = live->phi_limit;
    m->energy_limit = live->energy_limit;
    if (m->method == M_EXPONENTIAL) {
        const size_t nx = (size_t)m->nx;          /* what prepare writes of A and B */
        memcpy(m->dv.A, live->dv.A, nx * nx * sizeof m->dv.A[0]);
        memcpy(m->dv.B, live->dv.B, nx * sizeof m->dv.B[0]);
        m->dv.ex[0].h = m->dv.ex[1].h = -1.0;   /* empty (fpm_model_keep carries them over) */
    }
    m->ready = 1;
    return 1;
}

int fpm_model_load(fpm_model *m, fpm_reader *r, int initialized, const fpm_model *live)
{
    fpm_logger lg;
    stepper s;
    double k, phi, norm2 = 0.0;
    int init, i, stepped = 0;
    const char *bad = "";
    lg = fpm_reader_logger(r);
    fpm_get_finite(r, "t0", &m->t0);
    fpm_get_f64(r, "dF_c", &m->dF);             /* any values: legal calls can set them */
    fpm_get_f64(r, "d2F_c", &m->d2F);
    if (!fpm_get_int_in(r, "initialized", 0, 1, &init)) return 0;
    if (initialized >= 0 && init != initialized)
        return fpm_reject(r, "the model is %sinitialised in a state that needs %s",
                          init ? "" : "not ", initialized ? "an initialised one" : "none");
    if (!init) return 1;                        /* prepared again when an output is read */
    /* the parameters with the checks of initialisation, and everything derived from them:
     * sizes, method, modal data, the plant, the linear model */
    if (!prepared_like(m, live, r) && !prepare(m, &lg)) return 0;
    m->initialized = 1;
    s = m->s;
    fpm_get_int_in(r, "failed", 0, 1, &m->failed);
    fpm_get_str(r, "the refusal's reason", m->error, sizeof m->error);
    fpm_get_finite(r, "t", &s.t);
    fpm_get_finite(r, "t_base", &s.t_base);
    fpm_get_f64(r, "k", &k);
    for (i = 0; i < m->nx; i++) fpm_get_finite(r, "the state y", &s.y[i]);
    for (i = 0; i < m->nx; i++) fpm_get_finite(r, "the derivative f", &s.f[i]);
    fpm_get_finite(r, "h_abs", &s.h_abs);
    fpm_get_finite(r, "u", &s.u);
    fpm_get_finite(r, "du", &s.du);
    fpm_get_finite(r, "d2u", &s.d2u);
    fpm_get_finite(r, "tu", &s.tu);
    fpm_get_int_in(r, "prev_poly", 0, 1, &s.prev_poly);
    for (i = 0; i < 4; i++) fpm_get_finite(r, "the input the method's data belong to", &s.prev[i]);
    fpm_get_int_in(r, "stepped", 0, 1, &stepped);
    if (m->exact)
        for (i = 0; i < 4 * m->xb_p.nq; i++)
            fpm_get_finite(r, "the exact beam's state", &m->xb.s[i]);
    if (r->why[0] != '\0') return 0;
    /* what legal calls leave: a grid counted from t_base, time not before the start, an
     * adaptive step > 0, and a state that passed the divergence checks */
    if (!(k >= 0.0 && k <= 9007199254740992.0 && k < (double)(LONG_MAX / 2) && k == floor(k)))
        return fpm_reject(r, "k = %g is not a substep count", k);
    if (!(s.t >= m->t0 && s.t_base >= m->t0 && s.t_base <= s.t))
        return fpm_reject(r, "the times t0 = %.17g, t_base = %.17g, t = %.17g are out of order",
                          m->t0, s.t_base, s.t);
    if (!(s.h_abs > 0.0)) return fpm_reject(r, "h_abs = %g is not positive", s.h_abs);
    if (!m->failed) m->error[0] = '\0';
    s.k = (long)k;
    if (m->exact) return xb_load(m, r, &s, stepped);
    if (r->interface == FPM_MODEL_EXCHANGE) {
        /* Model Exchange: any finite state the importer may set (fpm_model_set_states takes
         * it, beyond the divergence bounds too: an integrator's trial point), never a doStep's
         * input polynomial */
        if (stepped)
            return fpm_reject(r, "a Model-Exchange state cannot hold a communication step's "
                              "input (stepped = 1)");
        m->s = s;
        m->stepped = 0;
        memcpy(m->y_acc, s.y, sizeof m->y_acc);
        m->out_fresh = m->energy_fresh = 0;
        return 1;
    }
    for (i = 0; i < m->nx; i++) norm2 += s.y[i] * s.y[i];
    phi = s.y[1];
    if (!(norm2 <= STATE_NORM2_LIMIT))
        return fpm_reject(r, "the state's norm %g exceeds 1e100", sqrt(norm2));
    if (!(fabs(phi) <= m->phi_limit))
        return fpm_reject(r, "|phi| = %g exceeds phi_limit = %g", fabs(phi), m->phi_limit);
    m->s = s;
    m->stepped = stepped;
    memcpy(m->y_acc, s.y, sizeof m->y_acc);   /* the last accepted state is the stepper's */
    if (!outputs_ok(m, &bad)) return fpm_reject(r, "the output %s would not be finite", bad);
    if (!(fabs(m->out[FP_OUT_ENERGY]) <= m->energy_limit))
        return fpm_reject(r, "|energy| = %g exceeds energy_limit = %g",
                          fabs(m->out[FP_OUT_ENERGY]), m->energy_limit);
    return 1;
}

/* ================================================================== Jacobians and output
 * derivatives (issue 24; fpm.h: fpm_model_nx, fpm_model_jacobian, fpm_model_output_derivatives)
 * on the kernel's fp_jacobian, fp_output_jacobian and fp_output_derivatives.
 *
 * States (Model Exchange's order): [x, phi, eta_1..eta_8, x_dot, phi_dot, eta_dot_1..eta_dot_8]
 * (FPM_N_ETA = 8 modes, the largest n_modes); the kernel's state of the instance's n modes maps
 * into it, and the rows and columns of modes beyond n are 0. Inputs: F_c. Outputs: the table's,
 * in value-reference order; those of modes beyond n are identically 0 (zero rows, derivatives 0).
 *
 * The point: the state y_acc (the state the last step accepted, or the one Model Exchange set)
 * and the force input_now() gives. Before initialisation: FPM_ERROR (the core refuses earlier). */
#define JAC_NQ (FPM_N_ETA + 2)
#define JAC_NX (2 * JAC_NQ)
#if FPM_N_MODES_MAX > FPM_N_ETA
#error "the Jacobian's states hold FPM_N_ETA modes"
#endif

size_t fpm_model_nx(void) { return JAC_NX; }

int fpm_model_max_output_derivative_order(void) { return FPM_OUTPUT_DERIVATIVE_ORDER; }
int fpm_model_offers_me(void) { return FPM_OFFERS_ME; }
int fpm_model_offers_jacobian(void) { return FPM_OFFERS_JACOBIAN; }

/* The force and its rate at the model's current time: after a doStep, the input polynomial that
 * step used (the stepper's: F_c and its derivatives at the step's start, or the held step average
 * of the exponential method), evaluated at the step's end; otherwise (after initialisation, and
 * always in Model Exchange, which takes no doStep) the input F_c set now and its derivative set
 * now (fmi2SetRealInputDerivatives; 0 in Model Exchange). "A step was taken" is the flag stepped:
 * set by a successful doStep, cleared by initialisation, saved and restored with FMU states. */
static void input_now(const fpm_model *m, double *u, double *du)
{
    const stepper *s = &m->s;
    if (m->stepped) {
        const double q = s->t - s->tu;
        if (s->du != 0.0 || s->d2u != 0.0) {
            *u = s->u + q * (s->du + 0.5 * q * s->d2u);
            *du = s->du + q * s->d2u;
        } else {
            *u = s->u;
            *du = 0.0;
        }
    } else {
        *u = m->v.real[VR_F_c];
        *du = m->dF;
    }
}

/* The kernel's output row (FP_OUT_*) of output vr; -1: identically 0 (a mode beyond n_modes);
 * -2: not an output. */
static int kernel_row(const fpm_model *m, unsigned vr)
{
    int j;
    switch (vr) {
    case VR_x_o: return FP_OUT_X;
    case VR_x_dot: return FP_OUT_XDOT;
    case VR_phi_o: return FP_OUT_PHI_O;
    case VR_omega_o: return FP_OUT_OMEGA_O;
    case VR_phi: return FP_OUT_PHI;
    case VR_tip_deflection: return m->n ? FP_OUT_TIP : -1;
    case VR_energy: return FP_OUT_ENERGY;
    default:
        for (j = 0; j < FPM_N_ETA; j++)
            if (vr == fpm_eta_vrs[j]) return j < m->n ? FP_OUT_ETA + j : -1;
    }
    return -2;
}

/* The Model-Exchange index of the kernel's state i. */
static int me_index(const fpm_model *m, int i)
{
    return i < m->nq ? i : JAC_NQ + (i - m->nq);
}

static int jac_ready(const fpm_model *m, const fpm_logger *lg, const char *what, double *u,
                     double *du)
{
    if (!m->initialized) {
        fpm_log(lg, FPM_ERROR, "%s: the model is not initialised", what);
        return 0;
    }
    input_now(m, u, du);
    if (!isfinite(*u) || !isfinite(*du)) {
        fpm_log(lg, FPM_ERROR, "%s: the input F_c = %g (rate %g) is not finite at t = %.17g",
                what, *u, *du, fpm_model_time(m));
        return 0;
    }
    return 1;
}

int fpm_model_jacobian(fpm_model *m, const fpm_logger *lg, double *A, double *B, double *C,
                       double *D)
{
    double J[NXMAX * NXMAX], b[NXMAX], Ck[(FP_OUT_ETA + NMAX) * NXMAX], work[4 * NXMAX];
    double u, du;
    int nx = m->nx, i, j, nu = 0, ny = 0;
    unsigned vr;
    if (m->exact || m->p.stiffened)
        return xb_refuse(m, lg, "directional derivatives and the linearisation");
    for (vr = 0; vr < FPM_MAX_VARS; vr++)
        if (fpm_vars[vr].name != NULL) {
            nu += fpm_vars[vr].causality == FPM_INPUT;
            ny += fpm_vars[vr].causality == FPM_OUTPUT;
        }
    if (!jac_ready(m, lg, "the linearisation", &u, &du)) return FPM_ERROR;
    if (A != NULL || B != NULL) {
        int rc = fp_jacobian(&m->p, m->y_acc, u, J, b, work);
        if (rc != FP_OK) {
            fpm_log(lg, FPM_ERROR, "the Jacobian of the derivatives is not finite at t = %.17g "
                    "(F_c = %g)", fpm_model_time(m), u);
            return FPM_ERROR;
        }
        if (A != NULL) {
            for (i = 0; i < JAC_NX * JAC_NX; i++) A[i] = 0.0;
            for (i = 0; i < nx; i++)
                for (j = 0; j < nx; j++)
                    A[me_index(m, i) * JAC_NX + me_index(m, j)] = J[i * nx + j];
        }
        if (B != NULL) {
            int k = 0;
            for (i = 0; i < JAC_NX * nu; i++) B[i] = 0.0;
            for (vr = 0; vr < FPM_MAX_VARS; vr++)
                if (fpm_vars[vr].name != NULL && fpm_vars[vr].causality == FPM_INPUT) {
                    if (vr == VR_F_c)
                        for (i = 0; i < nx; i++) B[me_index(m, i) * nu + k] = b[i];
                    k++;
                }
        }
    }
    if (C != NULL) {
        int k = 0;
        if (fp_output_jacobian(&m->p, m->y_acc, Ck) != FP_OK) {
            fpm_log(lg, FPM_ERROR, "the Jacobian of the outputs is not finite at t = %.17g",
                    fpm_model_time(m));
            return FPM_ERROR;
        }
        for (i = 0; i < ny * JAC_NX; i++) C[i] = 0.0;
        for (vr = 0; vr < FPM_MAX_VARS; vr++)
            if (fpm_vars[vr].name != NULL && fpm_vars[vr].causality == FPM_OUTPUT) {
                const int row = kernel_row(m, vr);
                if (row >= 0)
                    for (j = 0; j < nx; j++) C[k * JAC_NX + me_index(m, j)] = Ck[row * nx + j];
                k++;
            }
    }
    if (D != NULL)                            /* no output depends on F_c directly */
        for (i = 0; i < ny * nu; i++) D[i] = 0.0;
    return FPM_OK;
}

/* The derivatives of every output at the state and input, in m->od_d1, m->od_d2: the last
 * evaluation's when the state, the input and its rate are those it was made at (bit for bit). */
static int od_ready(fpm_model *m, const fpm_logger *lg, double u, double du, unsigned vr,
                    int order)
{
    double work[4 * NXMAX];
    if (m->od_valid && memcmp(&m->od_u, &u, sizeof u) == 0
        && memcmp(&m->od_du, &du, sizeof du) == 0
        && memcmp(m->od_x, m->y_acc, (size_t)m->nx * sizeof(double)) == 0)
        return 1;
    m->od_valid = 0;
    if (fp_output_derivatives(&m->p, m->y_acc, u, du, m->od_d1, m->od_d2, work) != FP_OK) {
        fpm_log(lg, FPM_ERROR, "the derivative of order %d of %s is not finite at t = %.17g "
                "(F_c = %g, dF_c = %g)", order, fpm_vars[vr].name, fpm_model_time(m), u, du);
        return 0;
    }
    m->od_u = u;
    m->od_du = du;
    memcpy(m->od_x, m->y_acc, (size_t)m->nx * sizeof(double));
    m->od_valid = 1;
    return 1;
}

int fpm_model_output_derivatives(fpm_model *m, const fpm_logger *lg, size_t n,
                                 const unsigned vr[], const int order[], double values[])
{
    double u = 0.0, du = 0.0;
    int row, ready = 0, have = 0;
    size_t i;
    for (i = 0; i < n; i++) {
        if (m->exact || m->p.stiffened) return xb_refuse(m, lg, "output derivatives");
        if (vr[i] >= FPM_MAX_VARS || (row = kernel_row(m, vr[i])) == -2) {
            fpm_log(lg, FPM_ERROR, "value reference %u is not an output", vr[i]);
            return FPM_ERROR;
        }
        if (order[i] < 1 || order[i] > 2) {
            fpm_log(lg, FPM_ERROR, "the derivative of order %d of %s: orders 1 and 2 only",
                    order[i], fpm_vars[vr[i]].name);
            return FPM_ERROR;
        }
        if (!ready) {                         /* the input once for the request */
            if (!jac_ready(m, lg, "the output derivatives", &u, &du)) return FPM_ERROR;
            ready = 1;
        }
        if (row == -1) {                      /* a mode beyond n_modes: identically 0 */
            values[i] = 0.0;
            continue;
        }
        if (!have && !od_ready(m, lg, u, du, vr[i], order[i])) return FPM_ERROR;
        have = 1;
        values[i] = order[i] == 1 ? m->od_d1[row] : m->od_d2[row];
    }
    return FPM_OK;
}
/* ================================================================== end of Jacobians and output
 * derivatives */

/* ================================================================== the exact rung (issue 27)
 * fidelity = "exact": the geometrically exact beam of plant_fmu/exact.py (ANCF cable elements
 * hinged on the cart) on the kernel's fp_exact_*: n_elements elements (n_modes and
 * gravity_preload do not apply; the integrator is always generalized alpha, whatever integrator
 * says), Kelvin-Voigt damping beta = 2 zeta / omega_1 (omega_1 the first cantilever frequency of
 * the same mesh: the first mode has the damping ratio zeta, as in the floating frame).
 *
 * Stepping: Radau IIA (three stages, order 5, L-stable; fp_radau_step, Newton to 1e-9, at most
 * 30 iterations, as plant_fmu/exact.py's RadauIIA and orchestration/studies/exact_loop.py) at the
 * substep h = step, on the grid of the explicit methods (advance_fixed: full substeps, a
 * shortened last one when a communication point is off the grid). Implicit, because the beam's
 * axial modes (the first near 8000 rad/s at the paper's data) and the mesh's highest bending
 * modes are far above 1/h: an explicit method would need h below 1e-5 s; L-stable, so that what
 * h does not resolve is damped rather than folded into the resolved band (a host that samples
 * the outputs once per substep then sees no alias of it: docs/exact.md); fifth order, so that the
 * loop's bending modes keep their phase over thousands of steps. The force is the input
 * polynomial at each stage's time, held when it has no derivatives. The accelerations start
 * consistent with the first step's input (fp_radau_start when no step was taken yet).
 *
 * Outputs (fp_exact_outputs): x_o, x_dot, phi_o and omega_o from the tip node's slope, phi the
 * root tangent's angle, tip_deflection the tip's distance from the line of the root tangent,
 * energy T + V. The exact beam has no modal coordinates: eta_1 is the tip deflection in units of
 * the first cantilever mode's, tip_deflection / N_1(L) (the modal coordinate that alone would
 * give it; the floating frame's eta_1 where mode 1 dominates), and eta_2 .. eta_8 are 0.
 * The divergence checks are the floating frame's, with phi the root tangent's angle.
 *
 * Not offered (an Error with a message): Model Exchange (the beam's stiff axial modes call for
 * the implicit step inside the FMU), the linearisation (directional derivatives) and output
 * derivatives. FMU states save the integrator's state [q, qd, qdd, jerk] (4 nq doubles) after the
 * floating frame's items; a restore checks them finite, within the divergence bounds, with
 * finite outputs, energy and internal forces. */
#define XB_RHO_INF 0.9                    /* not used by Radau IIA (fp_exact's field) */
#define XB_TOL 1e-9                       /* plant_fmu/exact.py's RADAU_TOL */
#define XB_MAX_ITER 30

static int xb_refuse(const fpm_model *m, const fpm_logger *lg, const char *what)
{
    const char *rung = m->exact ? "exact" : "stiffened";
    fpm_log(lg, FPM_ERROR, "%s: the %s rung (fidelity = '%s') does not offer %s; the "
            "floating-frame rungs (fidelity = 'nonlinear' or 'linear') do", fpm_model_name, rung,
            rung, what);
    return FPM_ERROR;
}

/* The kernel's data and the undeformed beam at phi0 (rotating at phi_dot0) on the cart at x0,
 * x_dot0 (exact.py: CableMesh.straight); the accelerations 0 until the first step. */
static int xb_prepare(fpm_model *m, const fpm_logger *lg)
{
    const double *r = m->v.real;
    fp_exact *p = &m->xb_p;
    const int ne = (int)r[VR_n_elements];
    const double L = r[VR_L], rhoA = r[VR_rho] * r[VR_EA] / r[VR_E];
    const double omega1 = sqrt(fpm_unit_lam[ne - 1][0] * r[VR_EI] / (rhoA * pow(L, 4.0)));
    const double c = cos(r[VR_phi0]), sn = sin(r[VR_phi0]), w = r[VR_phi_dot0];
    double e[4 * (FPM_NE_MAX + 1)], ed[4 * (FPM_NE_MAX + 1)];
    int i, nq;
    memset(p, 0, sizeof *p);
    p->ne = ne;
    p->L = L;
    p->EA = r[VR_EA];
    p->EI = r[VR_EI];
    p->rhoA = rhoA;
    p->g = r[VR_g];
    p->m = r[VR_m];
    /* the damping law: Kelvin-Voigt (material) or modal (in the root tangent's frame,
     * fp_exact_modal; computed here, from the parameters, at every preparation) */
    p->beta_kv = m->xb_kv ? 2.0 * r[VR_zeta] / omega1 : 0.0;
    p->modal = NULL;
    p->h = m->h;
    p->rho_inf = XB_RHO_INF;
    p->tol = XB_TOL;
    p->max_iter = XB_MAX_ITER;
    if (fp_exact_prepare(p) != FP_OK || !isfinite(p->beta_kv)) {
        fpm_log(lg, FPM_ERROR, "bad parameter: the exact beam's data are out of range (L = %g, "
                "EA = %g, EI = %g, rhoA = %g, m = %g, g = %g, zeta = %g, step = %g)", L,
                r[VR_EA], r[VR_EI], rhoA, r[VR_m], r[VR_g], r[VR_zeta], m->h);
        return 0;
    }
    if (fp_radau_work_size(p) > XB_WORK_MAX
        || fp_exact_modal_size(p) > (long)(sizeof m->xb.modal / sizeof(double))
        || fp_exact_modal_work_size(p) > (long)(sizeof m->xb.mwork / sizeof(double))) {
        fpm_log(lg, FPM_ERROR, "the exact rung's work (%ld doubles) exceeds its buffer (a broken "
                "build)", fp_radau_work_size(p));
        return 0;
    }
    if (!m->xb_kv && r[VR_zeta] > 0.0) {
        /* formed once per set of the data it depends on (its cost grows as n_elements^3: a
         * host that reads outputs before initialisation prepares at every read) */
        const double key[8] = {(double)ne, L, r[VR_EA], r[VR_EI], rhoA, r[VR_g], r[VR_m],
                               r[VR_zeta]};
        if (!m->xb.modal_ok || memcmp(key, m->xb.modal_key, sizeof key) != 0) {
            m->xb.modal_ok = 0;
            if (fp_exact_modal(p, r[VR_zeta], m->xb.modal, m->xb.mwork) != FP_OK) {
                fpm_log(lg, FPM_ERROR, "bad parameter: the modal damping law of the exact beam "
                        "could not be formed (its clamped modes: EA = %g, EI = %g, rhoA = %g, "
                        "n_elements = %d)", r[VR_EA], r[VR_EI], rhoA, ne);
                return 0;
            }
            memcpy(m->xb.modal_key, key, sizeof key);
            m->xb.modal_ok = 1;
        }
        p->modal = m->xb.modal;
    }
    m->xb_ps = *p;
    m->xb_n1 = fpm_unit_tip_defl[ne - 1][0] * (1.0 / sqrt(rhoA * L));
    if (!(isfinite(m->xb_n1) && fabs(m->xb_n1) > 0.0)) {
        fpm_log(lg, FPM_ERROR, "bad parameter: the first mode's tip deflection N_1(L) = %g is "
                "not finite and nonzero (from rho, EA, E, L)", m->xb_n1);
        return 0;
    }
    nq = p->nq;
    for (i = 0; i <= ne; i++) {
        const double si = L * i / ne;
        e[4 * i] = r[VR_x0] + si * (-sn);
        e[4 * i + 1] = si * c;
        e[4 * i + 2] = -sn;
        e[4 * i + 3] = c;
        ed[4 * i] = r[VR_x_dot0] + w * si * (-c);
        ed[4 * i + 1] = w * si * (-sn);
        ed[4 * i + 2] = w * (-c);
        ed[4 * i + 3] = w * (-sn);
    }
    memset(m->xb.s, 0, sizeof(double) * XB_S_MAX);
    m->xb.s[0] = e[0];
    m->xb.s[nq] = ed[0];
    for (i = 2; i < nq + 1; i++) {      /* q = e without the root's y (e[1]) */
        m->xb.s[i - 1] = e[i];
        m->xb.s[nq + i - 1] = ed[i];
    }
    return 1;
}

/* The outputs of the exact state into out (every one, energy included), eta_j = 0; 1 if the
 * state's norm is within the bound and every output is finite, else 0 (and *bad). */
static int xb_outputs_ok(fpm_model *m, const char **bad)
{
    const int nq = m->xb_p.nq;
    double norm2 = 0.0;
    int i;
    for (i = 0; i < 2 * nq; i++) norm2 += m->xb.s[i] * m->xb.s[i];
    m->out_fresh = m->energy_fresh = 0;
    if (!(norm2 <= STATE_NORM2_LIMIT)) {
        if (bad) *bad = "the state's norm";
        return 0;
    }
    if (fp_exact_outputs(&m->xb_p, m->xb.s, 1, m->out, m->xb.work) != FP_OK) {
        if (bad) *bad = "of the exact beam (a tangent of zero length)";
        return 0;
    }
    for (i = 0; i < NMAX; i++) m->out[FP_OUT_ETA + i] = 0.0;
    m->out[FP_OUT_ETA] = m->out[FP_OUT_TIP] / m->xb_n1;
    if (!isfinite(m->out[FP_OUT_ETA])) {
        if (bad) *bad = "eta_1";
        return 0;
    }
    m->out_fresh = m->energy_fresh = 1;
    return 1;
}

/* The deepest halving of a Radau substep whose Newton iteration fails (a substep of h is then
 * taken as up to 2^XB_SPLIT_MAX substeps of h / 2^XB_SPLIT_MAX). */
#define XB_SPLIT_MAX 4

/* One Radau step of h from t0 (the time since the input polynomial's start) into xb.s, under
 * the input polynomial; a step whose Newton iteration fails is taken as two halves, down to
 * depth XB_SPLIT_MAX. p: a prepared fp_exact whose h is overwritten. FP_OK or the kernel's code;
 * xb.s unchanged on failure. */
static int xb_radau(fpm_model *m, fp_exact *p, double t0, double h, int depth, long *iters)
{
    const stepper *s = &m->s;
    const double s6 = sqrt(6.0), c[3] = {(4.0 - s6) / 10.0, (4.0 + s6) / 10.0, 1.0};
    fp_radau_force F;
    int i, rc;
    if (p->h != h) {
        p->h = h;
        if (fp_exact_prepare(p) != FP_OK) return FP_BADARG;
    }
    memset(&F, 0, sizeof F);
    for (i = 0; i < 3; i++) {
        const double dt = t0 + c[i] * h;
        F.F0[i] = s->u + dt * (s->du + 0.5 * dt * s->d2u);
    }
    rc = fp_radau_step(p, &F, m->xb.s, m->xb.work, iters, NULL);
    if (rc != FP_NOCONVERGE || depth >= XB_SPLIT_MAX) return rc;
    rc = xb_radau(m, p, t0, 0.5 * h, depth + 1, iters);
    if (rc != FP_OK) return rc;
    return xb_radau(m, p, t0 + 0.5 * h, 0.5 * h, depth + 1, iters);
}

/* n substeps of h from the stepper's time (substeps() for the exact rung); 0 with why. */
static int xb_substeps(fpm_model *m, double h, long n, char *why)
{
    static const char *WHY[] = {"", "bad argument", "a residual is not finite",
                                "", "", "Newton did not converge (or its matrix is singular)"};
    stepper *s = &m->s;
    fp_exact *p = &m->xb_ps;                    /* its h follows the substep (xb_radau) */
    long done = 0, iters = 0, q;
    int rc = FP_OK;
    for (q = 0; q < n && rc == FP_OK; q++) {   /* the force at each stage's time */
        const double t0 = (s->t_base + (double)(s->k + q) * h) - s->tu;
        memcpy(m->xb.saved2, m->xb.s, sizeof(double) * 4 * m->xb_p.nq);
        iters = 0;
        rc = xb_radau(m, p, t0, h, 0, &iters);
        m->xb_work += (double)iters * m->xb_p.ne;
        if (rc == FP_OK) done++;
        else memcpy(m->xb.s, m->xb.saved2, sizeof(double) * 4 * m->xb_p.nq);
        if (rc == FP_OK && q + 1 < n && m->xb_work > (double)FPM_MAX_EXACT_WORK) {
            s->k += done;
            s->t = s->t_base + s->k * h;
            snprintf(why, FPM_MSG_MAX, "the exact rung's budget of %ld element-iterations per "
                     "doStep ran out at t = %.17g (%.17g spent on %d elements, Newton iterations "
                     "and halvings included): take shorter communication steps, a larger plant "
                     "step or fewer elements", FPM_MAX_EXACT_WORK, s->t, m->xb_work, m->xb_p.ne);
            return -1;
        }
    }
    s->k += done;
    s->t = s->t_base + s->k * h;
    if (rc != FP_OK) {
        snprintf(why, FPM_MSG_MAX, "the exact beam's Radau IIA substep from t = %.17g "
                 "(h = %.17g, also halved %d times) failed: %s", s->t, h, XB_SPLIT_MAX,
                 rc >= 0 && rc <= FP_NOCONVERGE && WHY[rc][0] ? WHY[rc] : "an error");
        return 0;
    }
    return 1;
}

/* The divergence checks at the exact state (the floating frame's, phi the root tangent's
 * angle); 1, or 0 with why. */
static int xb_checks(fpm_model *m, double t, char *why)
{
    const char *bad = "";
    double phi;
    if (!xb_outputs_ok(m, &bad)) {
        snprintf(why, FPM_MSG_MAX, "divergence at t = %.17g: the output %s would not be finite",
                 t, bad);
        return 0;
    }
    phi = m->out[FP_OUT_PHI];
    if (!(fabs(phi) <= m->phi_limit)) {
        snprintf(why, FPM_MSG_MAX, "divergence at t = %.17g: |phi| = %.17g exceeds phi_limit = "
                 "%.17g", t, fabs(phi), m->phi_limit);
        return 0;
    }
    if (!(fabs(m->out[FP_OUT_ENERGY]) <= m->energy_limit)) {
        snprintf(why, FPM_MSG_MAX, "divergence at t = %.17g: |energy| = %.17g exceeds "
                 "energy_limit = %.17g", t, fabs(m->out[FP_OUT_ENERGY]), m->energy_limit);
        return 0;
    }
    return 1;
}

/* fpm_model_step for the exact rung (its input checked already). */
static int xb_step(fpm_model *m, const fpm_logger *lg, double t, double h)
{
    const int n4 = 4 * m->xb_p.nq;
    char why[FPM_MSG_MAX];
    const stepper saved = m->s;
    stepper *s = &m->s;
    int rc;
    memcpy(m->xb.saved, m->xb.s, sizeof(double) * n4);
    m->xb_work = 0.0;
    s->u = m->v.real[VR_F_c];
    s->du = m->dF;
    s->d2u = m->d2F;
    s->tu = t;
    if (!m->stepped) {                          /* consistent accelerations under the input */
        fp_radau_force F;
        memset(&F, 0, sizeof F);
        F.F0[0] = F.F0[1] = F.F0[2] = s->u;
        if (fp_radau_start(&m->xb_p, &F, m->xb.s, m->xb.work) != FP_OK) {
            m->s = saved;
            memcpy(m->xb.s, m->xb.saved, sizeof(double) * n4);
            fpm_log(lg, FPM_DISCARD, "the exact beam's accelerations at t = %.17g are not finite "
                    "(F_c = %g); step rejected, state unchanged", t, s->u);
            return FPM_DISCARD;
        }
    }
    rc = t + h <= s->t ? 1 : advance_fixed(m, t + h, why);
    if (rc < 0) {                   /* a cap or the budget: nothing accepted, retry allowed */
        m->s = saved;
        memcpy(m->xb.s, m->xb.saved, sizeof(double) * n4);
        xb_outputs_ok(m, NULL);
        fpm_log(lg, FPM_DISCARD, "%s; step rejected, state unchanged", why);
        return FPM_DISCARD;
    }
    if (rc == 0 || !xb_checks(m, t + h, why)) {
        memcpy(m->xb.s, m->xb.saved, sizeof(double) * n4);
        xb_outputs_ok(m, NULL);                 /* the outputs of the state restored */
        return diverged(m, lg, &saved, why);
    }
    m->stepped = 1;
    return FPM_OK;
}

/* The end of fpm_model_load for the exact rung (its state read into xb.s): co-simulation only,
 * and a state the checks of a step accept, whose internal forces are finite. */
static int xb_load(fpm_model *m, fpm_reader *r, const stepper *s, int stepped)
{
    char why[FPM_MSG_MAX];
    const int nq = m->xb_p.nq;
    double *f = m->xb.saved;                    /* scratch */
    if (r->interface == FPM_MODEL_EXCHANGE)
        return fpm_reject(r, "the exact rung (fidelity = 'exact') has no Model Exchange");
    m->s = *s;
    m->stepped = stepped;
    if (!xb_checks(m, s->t, why)) return fpm_reject(r, "%s", why);
    if (fp_exact_forces(&m->xb_p, m->xb.s, m->xb.s + nq, 0.0, f, NULL, NULL, NULL, m->xb.work)
        != FP_OK)
        return fpm_reject(r, "the exact beam's internal forces would not be finite");
    return 1;
}
/* ================================================================== end of the exact rung */
