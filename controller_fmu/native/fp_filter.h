/*
 * fp_filter.h - the compiled kernel of the controller: PD on the tip sensors, then a unit-DC-gain
 * low-pass filter of order 0, 1 or 2, discretised exactly over a step (controller_fmu/pd_lowpass.py
 * is the readable specification; docs/model.md section 5):
 *
 *     e   = kx x_o + kp phi_o + kd omega_o
 *     F_c = -sat(H(s) e),  H = 1, wc / (s + wc) or wc^2 / (s^2 + 2 zf wc s + wc^2)
 *
 * The filter state xc (order doubles, the filter output first) follows xc' = Af xc + Bf e
 * (controllable canonical form). Over a step h with the error signal the polynomial
 * e(t + s) = e0 + e1 s + e2 s^2 / 2, the exact step is xc(t + h) = Ad xc(t) + G [e0, e1, e2],
 * with Ad and G blocks of the matrix exponential of the filter driven by a chain of three
 * integrators (with a held input, e1 = e2 = 0 and only G's first column counts).
 *
 * Contract: portable C99 plus libm; no global state, no allocation (the matrix exponential works
 * in a buffer of the caller, fpf_expm_work_size() doubles); SI units (rad, rad/s, s, N); matrices
 * row-major; every function that can fail returns an FPF_* code and leaves its outputs untouched
 * on failure.
 */
#ifndef FP_FILTER_H
#define FP_FILTER_H

#ifdef __cplusplus
extern "C" {
#endif

/* Exported from the kernel's own library; a native FMU that links the sources defines FPF_API
 * empty, so that it exports the FMI functions alone. */
#ifndef FPF_API
#if defined(_WIN32)
#define FPF_API __declspec(dllexport)
#else
#define FPF_API __attribute__((visibility("default")))
#endif
#endif

#define FPF_ABI 4

#define FPF_OK 0
#define FPF_BADARG 1      /* an argument is out of range (nothing was done) */
#define FPF_NONFINITE 2   /* the result would not be finite (state left unchanged) */

/* Largest matrix fpf_discretize() builds: order 2 plus the chain of three integrators. */
#define FPF_MAX_AUG 5

/* The controller's parameters (ControllerParams). */
typedef struct fpf_filter {
    int order;             /* 0 (no filter), 1 or 2 */
    double kp, kd, kx;     /* gains on phi_o (N/rad), omega_o (N s/rad), x_o (N/m) */
    double cutoff;         /* wc, rad/s, > 0 */
    double damping;        /* zf of the 2nd-order filter, >= 0 */
    double force_limit;    /* |F_c| <= force_limit, > 0 (may be +inf) */
} fpf_filter;

/* The ABI version FPF_ABI and the sha256 (hex) of the sources the library was built from. */
FPF_API int fpf_abi(void);
FPF_API const char *fpf_source_digest(void);

/* FPF_OK if the parameters are in range, else FPF_BADARG. */
FPF_API int fpf_check(const fpf_filter *f);

/* Doubles of work fpf_expm() needs for an n x n matrix. */
FPF_API long fpf_expm_work_size(int n);

/* E = expm(A) for the n x n matrix A (1 <= n): scaling and squaring with a diagonal Pade
 * approximant of degree 3, 5, 7, 9 or 13 chosen from the 1-norm (Higham 2005). A and E may not
 * overlap; work: fpf_expm_work_size(n) doubles. FPF_OK, FPF_BADARG (n < 1, a non-finite entry)
 * or FPF_NONFINITE (the result overflows or the Pade denominator is singular). */
FPF_API int fpf_expm(int n, const double *A, double *E, double *work);

/* The exact discretisation over h > 0: Ad (order x order) and G (order x 3: e0, e1, e2) when
 * poly is nonzero; with poly = 0 only the held-input column, G (order x 1), from the smaller
 * matrix [[Af h, Bf h], [0, 0]]. Nothing to do for order 0. */
FPF_API int fpf_discretize(const fpf_filter *f, double h, int poly, double *Ad, double *G);

/* The error polynomial's coefficients from the sensors and their time derivatives:
 * y = [x_o, phi_o, omega_o, dx_o, dphi_o, domega_o, d2x_o, d2phi_o, d2omega_o] -> e[3]. */
FPF_API void fpf_error(const fpf_filter *f, const double *y, double *e);

/* One step: xc <- Ad xc + G e (G: order x 3, e: 3 coefficients), then *F = the saturated force
 * -sat(xc[0]). For order 0 there is no state and *F = -sat(e[0]). FPF_OK, or FPF_NONFINITE with
 * xc and *F unchanged. */
FPF_API int fpf_step(const fpf_filter *f, const double *Ad, const double *G, const double *e,
                     double *xc, double *F);

/* ---- The sampled controller's filter (controller_fmu/sampled.py, the specification) ----------
 * The filter as a difference equation over the sample period T > 0: xf[k+1] = Ad xf[k] + Bd e[k],
 * v[k] = Cd xf[k] + Dd e[k] (the filtered error; the force is -sat(v)). tustin = 1: the bilinear
 * map prewarped at the cutoff, s = c (z - 1) / (z + 1), c = cutoff / tan(cutoff T / 2), in the
 * state space of the generalised bilinear transform (M = I - Af / c, Ad = M^-1 (I + Af / c),
 * Bd = M^-1 Bf 2 / c, Cd = Cf M^-1, Dd = Df + Cf Bd / 2); it needs cutoff T < pi. tustin = 0: the
 * zero-order-hold equivalent (Ad = exp(Af T), Bd = int_0^T exp(Af s) ds Bf, Cd = Cf, Dd = Df).
 * Ad: order x order, Bd: order, Cd: order, *Dd (order 0: Dd = 1 and nothing else). FPF_OK,
 * FPF_BADARG (bad parameters, T, or cutoff T >= pi with tustin) or FPF_NONFINITE. */
FPF_API int fpf_sampled(const fpf_filter *f, double T, int tustin, double *Ad, double *Bd,
                        double *Cd, double *Dd);

/* ---- The continuous-time filter, its linearisation and output derivatives (issue 24) --------
 * The state xc (order doubles) follows xc' = Af xc + Bf e with e = kx x_o + kp phi_o + kd omega_o
 * and Af, Bf the controllable canonical form above (order 1: xc' = wc (e - xc); order 2:
 * xc1' = xc2, xc2' = wc^2 (e - xc1) - 2 zf wc xc2); F_c = -sat(xc[0]), and with order 0 (no
 * state) F_c = -sat(e), a direct feedthrough.
 *
 * The saturation sat(v) = min(max(v, -L), L) is differentiated as the branch that computes its
 * value: slope 1 for |v| <= L (the identity branch, bounds included, where sat(v) = v exactly),
 * 0 for |v| > L; its second derivative is 0 (piecewise linear). Exactly at the bound this is the
 * derivative from inside; the one-sided derivative outwards is 0 (a set of measure zero: a state
 * or error signal exactly equal to the limit). With force_limit = +inf or the largest double
 * every finite v has slope 1. */

/* dxc = xc' for the error signal e (order doubles; nothing for order 0). FPF_OK, or
 * FPF_NONFINITE (dxc unchanged) if the result would not be finite. */
FPF_API int fpf_rhs(const fpf_filter *f, const double *xc, double e, double *dxc);

/* The exact linearisation at the state xc with the error signal e (e only matters for order 0):
 * A = d xc'/d xc (order x order), B = d xc'/d y (order x 3), C = d F_c/d xc (1 x order),
 * D = d F_c/d y (1 x 3), row-major, with the inputs y in the FMU's table order
 * [phi_o, omega_o, x_o] (not fpf_error's). Any pointer may be NULL (not wanted). FPF_OK or
 * FPF_NONFINITE (xc or e not finite). */
FPF_API int fpf_linearize(const fpf_filter *f, const double *xc, double e, double *A, double *B,
                          double *C, double *D);

/* d[k - 1] = the k-th time derivative of F_c, k = 1..4, at the state xc for the error signal
 * given as its value and time derivatives e = [e, e', e''] at that instant (fpf_error of the
 * sensors' polynomial, of degree 2: its third and fourth derivatives are 0): exact (the filter's
 * own equations differentiated, and the saturation's slope as above). FPF_OK or FPF_NONFINITE. */
FPF_API int fpf_output_derivatives(const fpf_filter *f, const double *xc, const double *e,
                                   double *d);

#ifdef __cplusplus
}
#endif

#endif /* FP_FILTER_H */
