/*
 * kernel_check.c - drives both C kernels through every entry point, for the build under
 * -fsanitize=address,undefined (tests/common/test_kernel_sanitizers.py). Besides "no memory error
 * and no undefined behaviour", it checks properties with known answers:
 *   - the fixed-step loop over n substeps equals n calls of one substep (held input), bitwise;
 *   - the adaptive loop in chunks (a cap of 2 steps per call) equals one call, bitwise;
 *   - Euler far beyond its stability limit stops with FP_NONFINITE and a finite state;
 *   - a minimum step the error control cannot meet gives FP_UNDERFLOW;
 *   - bad arguments give FP_BADARG / FPF_BADARG and change nothing;
 *   - expm(0) = I, expm(diag(a, b)) = diag(e^a, e^b), expm([[0, t], [0, 0]]) = [[1, t], [0, 1]];
 *   - the first-order filter: Ad = exp(-wc h), held-input gain 1 - exp(-wc h);
 *   - the exact rung's Radau IIA (fp_radau_*, 1, 3 and 8 elements, closed loop, failures)
 *   - the exact rung (fp_exact_*, 1, 3 and 8 elements, closed loop with the force row outside
 *     the band): n steps in one call equal n calls, bitwise; a free fall keeps the beam's length;
 *     a non-finite force, a huge step and one Newton iteration give their codes and leave the
 *     state unchanged and finite.
 * Usage: kernel_check PLANT_DATA (written by the test from plant_fmu/beam.py: n, I0, I1, I2, g,
 * then I3, I5, K, D, tip_slope, tip_defl (n each) and Kg (n x n)). Prints "ok <checks>".
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fp_filter.h"
#include "fp_plant.h"

static int checks = 0, failures = 0;

static void check(int cond, const char *what)
{
    checks++;
    if (!cond) {
        failures++;
        fprintf(stderr, "FAILED: %s\n", what);
    }
}

static double *read_doubles(FILE *f, int n)
{
    double *a = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    int i;
    for (i = 0; i < n; i++)
        if (fscanf(f, "%lf", &a[i]) != 1) exit(2);
    return a;
}

static void plant_checks(fp_plant *p)
{
    const int nx = p->nx;
    const fp_tableau *rk4 = fp_builtin_tableau(FP_RK4), *dp = fp_builtin_tableau(FP_DOPRI5);
    double *y = calloc((size_t)nx, sizeof(double)), *y2 = calloc((size_t)nx, sizeof(double));
    double *dx = calloc((size_t)nx, sizeof(double)), *f = calloc((size_t)nx, sizeof(double));
    double *f2 = calloc((size_t)nx, sizeof(double));
    double *work = calloc((size_t)fp_work_size(p, 7), sizeof(double));
    double *out = calloc((size_t)(FP_OUT_ETA + p->n), sizeof(double));
    fp_input held = {3.0, 0.0, 0.0, 0.0}, poly = {3.0, 200.0, -5e4, 0.0};
    fp_adaptive a;
    double tip[2], t, t2, atol = 1e-10;
    long done, k;
    int m, rc, same;

    y[1] = 0.3;
    y[nx / 2 + 1] = -0.2;
    if (p->n > 0) y[2] = 1e-3;
    fp_rhs(p, y, 1.0, dx);
    check(dx[0] == y[nx / 2], "rhs: dx/dt of x is x_dot");
    fp_tip(p, y, tip);
    fp_outputs(p, y, 1, out);
    check(out[FP_OUT_PHI_O] == tip[0] && out[FP_OUT_OMEGA_O] == tip[1], "outputs: tip angle");
    check(out[FP_OUT_ENERGY] == fp_energy(p, y), "outputs: energy");
    check(p->n == 0 || out[FP_OUT_ETA] == y[2], "outputs: modal coordinates");

    /* n substeps in one call = n calls of one substep (held input: the stage times do not
     * enter) */
    memcpy(y2, y, sizeof(double) * (size_t)nx);
    rc = fp_fixed_steps(p, -1, rk4, &held, 0.0, 1e-4, 10, y, work, &done);
    check(rc == FP_OK && done == 10, "fixed steps: ten substeps");
    for (k = 0; k < 10; k++) fp_fixed_steps(p, -1, rk4, &held, k * 1e-4, 1e-4, 1, y2, work, &done);
    same = 1;
    for (m = 0; m < nx; m++) same &= y[m] == y2[m];
    check(same, "fixed steps: one call of 10 = 10 calls of 1");
    rc = fp_fixed_steps(p, FP_SYMPLECTIC_EULER, NULL, &poly, 0.0, 1e-4, 10, y2, work, &done);
    check(rc == FP_OK && done == 10, "symplectic Euler with a polynomial input");

    /* instability: Euler with h = 0.05 on the bending modes overflows */
    if (p->n > 0) {
        rc = fp_fixed_steps(p, -1, fp_builtin_tableau(FP_EULER), &held, 0.0, 0.05, 1000000, y2,
                            work, &done);
        same = 1;
        for (m = 0; m < nx; m++) same &= isfinite(y2[m]) != 0;
        check(rc == FP_NONFINITE && done < 1000000 && same, "Euler blows up: last finite state");
    }
    check(fp_fixed_steps(p, -1, rk4, &held, 0.0, -1.0, 1, y, work, &done) == FP_BADARG,
          "fixed steps: h < 0 refused");
    check(fp_fixed_steps(p, -1, NULL, &held, 0.0, 1e-4, 1, y, work, &done) == FP_BADARG,
          "fixed steps: no tableau refused");

    /* adaptive: one call against calls capped at 2 accepted steps */
    fp_rhs(p, y, poly.u0, f);
    memcpy(y2, y, sizeof(double) * (size_t)nx);
    memcpy(f2, f, sizeof(double) * (size_t)nx);
    memset(&a, 0, sizeof a);
    a.rtol = 1e-8;
    a.atol = &atol;
    a.n_atol = 1;
    a.max_step = HUGE_VAL;
    a.max_steps = 1000000;
    a.h_abs = 1e-4;
    t = 0.0;
    rc = fp_dopri_advance(p, dp, &poly, &t, 5e-3, y, f, &a, work);
    check(rc == FP_OK && t == 5e-3 && a.nsteps > 2, "adaptive: reaches t_end");
    {
        fp_adaptive b = a;
        long steps = 0;
        b.h_abs = 1e-4;
        b.max_steps = 2;
        b.nsteps = 0;
        t2 = 0.0;
        do {
            rc = fp_dopri_advance(p, dp, &poly, &t2, 5e-3, y2, f2, &b, work);
            steps++;
        } while (rc == FP_CAP && steps < 100000);
        same = rc == FP_OK && t2 == t && b.nsteps == a.nsteps;
        for (m = 0; m < nx; m++) same &= y[m] == y2[m] && f[m] == f2[m];
        check(same, "adaptive: capped calls = one call");
    }
    a.min_step = 1e-3;
    a.rtol = 1e-14;
    atol = 1e-16;
    a.h_abs = 1e-3;
    rc = fp_dopri_advance(p, dp, &poly, &t, 1.0, y, f, &a, work);
    check(p->n == 0 || rc == FP_UNDERFLOW, "adaptive: step underflow reported");
    a.max_steps = 0;
    check(fp_dopri_advance(p, dp, &poly, &t, 2.0, y, f, &a, work) == FP_BADARG,
          "adaptive: a cap of 0 refused");
    check(fp_dopri_advance(p, rk4, &poly, &t, 2.0, y, f, &a, work) == FP_BADARG,
          "adaptive: a tableau without error weights refused");
    free(y);
    free(y2);
    free(dx);
    free(f);
    free(f2);
    free(work);
    free(out);
}

static void filter_checks(void)
{
    double work[9 * 8 * 8], A[4], E[4], Ad[4], G[6], x[2] = {0.1, -0.2}, e[3] = {1.0, 0.0, 0.0};
    double F = 0.0;
    fpf_filter flt = {1, 500.0, 5.0, 0.0, 100.0, 0.5, HUGE_VAL};
    const double h = 1e-3;
    int i;

    memset(A, 0, sizeof A);
    check(fpf_expm(2, A, E, work) == FPF_OK && E[0] == 1.0 && E[1] == 0.0 && E[3] == 1.0,
          "expm(0) = I");
    A[0] = -3.0;
    A[3] = 0.5;
    fpf_expm(2, A, E, work);
    check(fabs(E[0] - exp(-3.0)) <= 1e-15 * exp(-3.0) && fabs(E[3] - exp(0.5)) <= 2e-15 * exp(0.5)
          && E[1] == 0.0 && E[2] == 0.0, "expm of a diagonal matrix");
    A[0] = A[3] = 0.0;
    A[1] = 7.5;
    fpf_expm(2, A, E, work);
    check(E[0] == 1.0 && E[1] == 7.5 && E[2] == 0.0 && E[3] == 1.0, "expm of a nilpotent matrix");
    A[1] = NAN;
    check(fpf_expm(2, A, E, work) == FPF_BADARG, "expm: NaN refused");

    check(fpf_discretize(&flt, h, 0, Ad, G) == FPF_OK, "first-order filter, held");
    check(fabs(Ad[0] - exp(-100.0 * h)) <= 1e-15 && fabs(G[0] - (1.0 - exp(-100.0 * h))) <= 1e-15,
          "first-order filter: exp(-wc h) and 1 - exp(-wc h)");
    for (i = 2; i >= 0; i--) {
        flt.order = i;
        check(fpf_discretize(&flt, h, 1, Ad, G) == FPF_OK, "discretise, polynomial");
        check(fpf_step(&flt, Ad, G, e, x, &F) == FPF_OK && isfinite(F), "filter step");
    }
    flt.order = 2;
    fpf_discretize(&flt, h, 1, Ad, G);
    e[0] = HUGE_VAL;
    {
        double x0 = x[0], x1 = x[1], F0 = F;
        check(fpf_step(&flt, Ad, G, e, x, &F) == FPF_NONFINITE && x[0] == x0 && x[1] == x1
              && F == F0, "filter step: a non-finite input changes nothing");
    }
    check(fpf_discretize(&flt, -1.0, 1, Ad, G) == FPF_BADARG, "discretise: h < 0 refused");
    flt.order = 3;
    check(fpf_check(&flt) == FPF_BADARG, "filter order 3 refused");
}

static void exact_checks(int ne)
{
    fp_exact e;
    fp_exact_force F = {0.0, 0.3, 1.0, 500.0, 5.0}, bad = F;
    double *s, *s1, *work, *f, *K, *C, *M;
    long done, iters = 0, k;
    int nq, i, same = 1, finite = 1;
    memset(&e, 0, sizeof e);
    e.ne = ne; e.L = 1.0; e.EA = 4.2e8; e.EI = 875.0; e.rhoA = 15.6; e.g = 9.81; e.m = 5.0;
    e.beta_kv = 2e-3 / 150.0; e.h = 1e-4; e.rho_inf = 0.9; e.tol = 1e-11; e.max_iter = 30;
    check(fp_exact_prepare(&e) == FP_OK, "exact: data accepted");
    nq = e.nq;
    s = calloc((size_t)(4 * nq), sizeof(double));
    s1 = calloc((size_t)(4 * nq), sizeof(double));
    work = calloc((size_t)fp_exact_work_size(&e), sizeof(double));
    f = calloc((size_t)nq, sizeof(double));
    K = calloc((size_t)(nq * nq), sizeof(double));
    C = calloc((size_t)(nq * nq), sizeof(double));
    M = calloc((size_t)(nq * nq), sizeof(double));
    /* the straight beam at 0.5 rad from the vertical, at rest: r(s) = s t, r' = t */
    for (i = 0; i <= ne; i++) {
        double si = (double)i / ne, tx = -sin(0.5), ty = cos(0.5);
        if (i > 0) {
            s[4 * i - 1] = si * tx;
            s[4 * i] = si * ty;
        }
        s[4 * i + 1] = tx;
        s[4 * i + 2] = ty;
    }
    check(fp_exact_forces(&e, s, s + nq, 1.0, f, K, C, M, work) == FP_OK, "exact: forces");
    check(fp_exact_start(&e, &F, s, work) == FP_OK, "exact: start");
    memcpy(s1, s, sizeof(double) * (size_t)(4 * nq));
    check(fp_exact_steps(&e, &F, 20, s, work, &done, &iters) == FP_OK && done == 20,
          "exact: 20 steps in one call");
    for (k = 0; k < 20; k++)
        check(fp_exact_steps(&e, &F, 1, s1, work, &done, &iters) == FP_OK, "exact: one step");
    for (i = 0; i < 4 * nq; i++) same = same && s[i] == s1[i];
    check(same, "exact: 20 steps in one call equal 20 calls, bitwise");
    {   /* the tip's distance from the root stays the beam's length (to the axial strain) */
        double dx = s[nq - 4] - s[0], dy = s[nq - 3];
        check(fabs(sqrt(dx * dx + dy * dy) - 1.0) < 1e-6, "exact: the beam keeps its length");
    }
    memcpy(s1, s, sizeof(double) * (size_t)(4 * nq));
    bad.F0 = NAN;
    check(fp_exact_steps(&e, &bad, 3, s, work, &done, &iters) == FP_BADARG && done == 0,
          "exact: a non-finite force refused");
    bad = F;
    bad.kp = INFINITY;
    check(fp_exact_start(&e, &bad, s, work) == FP_BADARG, "exact: a non-finite gain refused");
    e.h = 1.0;
    check(fp_exact_prepare(&e) == FP_OK, "exact: h = 1 s accepted");
    check(fp_exact_steps(&e, &F, 3, s, work, &done, &iters) == FP_NOCONVERGE && done == 0,
          "exact: a huge step does not converge");
    e.h = 1e-4;
    e.max_iter = 1;
    check(fp_exact_prepare(&e) == FP_OK, "exact: one iteration accepted");
    check(fp_exact_steps(&e, &F, 3, s, work, &done, &iters) == FP_NOCONVERGE,
          "exact: one Newton iteration does not converge");
    for (i = 0; i < 4 * nq; i++) {
        same = same && s[i] == s1[i];
        finite = finite && isfinite(s[i]);
    }
    check(same && finite, "exact: failures leave the state unchanged and finite");
    e.max_iter = 0;
    check(fp_exact_prepare(&e) == FP_BADARG, "exact: max_iter = 0 refused");
    e.max_iter = 30;
    e.h = NAN;
    check(fp_exact_prepare(&e) == FP_BADARG, "exact: h = NaN refused");
    e.h = 1e-4;
    check(fp_exact_prepare(&e) == FP_OK, "exact: restored");
    {   /* the outputs (the native FMU's), and tangents of zero length: a code, no 1/0 */
        double out[FP_OUT_ENERGY + 1];
        check(fp_exact_outputs(&e, s, 1, out, work) == FP_OK && fabs(out[FP_OUT_PHI]) < 1.0,
              "exact: outputs");
        check(fp_exact_outputs(&e, s, 1, out, NULL) == FP_BADARG, "exact: energy without work");
        s[nq - 2] = s[nq - 1] = 0.0;
        check(fp_exact_outputs(&e, s, 0, out, NULL) == FP_NONFINITE, "exact: no tip tangent");
        for (i = 0; i < 4 * nq; i++) s[i] = 0.0;     /* every node at the root, at rest */
        check(fp_exact_forces(&e, s, s + nq, 0.0, f, NULL, NULL, NULL, work) == FP_NONFINITE,
              "exact: elements of no length");
        check(fp_exact_steps(&e, &F, 1, s, work, &done, &iters) == FP_NONFINITE,
              "exact: no step from elements of no length");
    }
    free(s); free(s1); free(work); free(f); free(K); free(C); free(M);
}

/* The Radau IIA step (fp_radau_*): held force and the closed loop (a stage law Q with the force
 * row outside the band), a step that does not converge, bad laws refused, failures leaving the
 * state unchanged; the work is fp_radau_work_size exactly (ASan sees an overrun). */
static void radau_checks(int ne)
{
    fp_exact e;
    fp_radau_force F, bad;
    double *s, *s1, *work, es[3];
    long iters = 0, k;
    int nq, i, same = 1, finite = 1;
    memset(&e, 0, sizeof e);
    memset(&F, 0, sizeof F);
    e.ne = ne; e.L = 1.0; e.EA = 4.2e8; e.EI = 875.0; e.rhoA = 15.6; e.g = 9.81; e.m = 5.0;
    e.beta_kv = 2e-3 / 150.0; e.h = 1e-3; e.rho_inf = 0.9; e.tol = 1e-9; e.max_iter = 30;
    check(fp_exact_prepare(&e) == FP_OK, "radau: data accepted");
    nq = e.nq;
    s = calloc((size_t)(4 * nq), sizeof(double));
    s1 = calloc((size_t)(4 * nq), sizeof(double));
    work = calloc((size_t)fp_radau_work_size(&e), sizeof(double));
    check(fp_radau_work_size(&e) >= fp_exact_work_size(&e), "radau: work covers the others'");
    for (i = 0; i <= ne; i++) {
        double si = (double)i / ne, tx = -sin(0.5), ty = cos(0.5);
        if (i > 0) {
            s[4 * i - 1] = si * tx;
            s[4 * i] = si * ty;
        }
        s[4 * i + 1] = tx;
        s[4 * i + 2] = ty;
    }
    F.kx = 1.0; F.kp = 500.0; F.kd = 5.0;
    for (i = 0; i < 3; i++) {
        F.F0[i] = 0.5 * i;
        F.Q[3 * i + i] = 0.3;                           /* feedback at every stage */
        F.Q[3 * i + (i + 1) % 3] = 0.05;
    }
    check(fp_radau_start(&e, &F, s, work) == FP_OK, "radau: start");
    for (i = 0; i < nq; i++) finite = finite && s[3 * nq + i] == 0.0;
    check(finite, "radau: the start's jerk is 0");
    for (k = 0; k < 20; k++)
        check(fp_radau_step(&e, &F, s, work, &iters, es) == FP_OK && isfinite(es[0])
              && isfinite(es[2]), "radau: a closed-loop step");
    check(iters >= 20 && iters <= 20L * e.max_iter, "radau: iterations counted");
    {   /* the tip's distance from the root stays the beam's length (to the axial strain) */
        double dx = s[nq - 4] - s[0], dy = s[nq - 3];
        check(fabs(sqrt(dx * dx + dy * dy) - 1.0) < 1e-6, "radau: the beam keeps its length");
    }
    {   /* the modal law: its blocks, then steps with it (the force reads them) */
        double *C = calloc((size_t)fp_exact_modal_size(&e), sizeof(double));
        double *mw = calloc((size_t)fp_exact_modal_work_size(&e), sizeof(double));
        check(fp_exact_modal(&e, 0.01, C, mw) == FP_OK, "radau: the modal law formed");
        check(fp_exact_modal(&e, NAN, C, mw) == FP_BADARG, "radau: a NaN zeta refused");
        e.modal = C;
        for (k = 0; k < 5; k++)
            check(fp_radau_step(&e, &F, s, work, &iters, es) == FP_OK, "radau: a modal step");
        e.modal = NULL;
        free(C);
        free(mw);
    }
    memset(F.Q, 0, sizeof F.Q);                         /* a held force */
    check(fp_radau_step(&e, &F, s, work, &iters, NULL) == FP_OK, "radau: a held-force step");
    memcpy(s1, s, sizeof(double) * (size_t)(4 * nq));
    bad = F;
    bad.F0[1] = NAN;
    check(fp_radau_step(&e, &bad, s, work, &iters, es) == FP_BADARG, "radau: NaN force refused");
    bad = F;
    bad.Q[4] = INFINITY;
    check(fp_radau_start(&e, &bad, s, work) == FP_BADARG, "radau: infinite law refused");
    check(fp_radau_step(&e, &F, s, NULL, &iters, es) == FP_BADARG, "radau: no work refused");
    e.h = 1.0;
    check(fp_exact_prepare(&e) == FP_OK, "radau: h = 1 s accepted");
    check(fp_radau_step(&e, &F, s, work, &iters, es) == FP_NOCONVERGE,
          "radau: a huge step does not converge");
    e.h = 1e-3;
    e.max_iter = 1;
    check(fp_exact_prepare(&e) == FP_OK, "radau: one iteration accepted");
    check(fp_radau_step(&e, &F, s, work, &iters, es) == FP_NOCONVERGE,
          "radau: one Newton iteration does not converge");
    for (i = 0; i < 4 * nq; i++) {
        same = same && s[i] == s1[i];
        finite = finite && isfinite(s[i]);
    }
    check(same && finite, "radau: failures leave the state unchanged and finite");
    e.max_iter = 30;
    check(fp_exact_prepare(&e) == FP_OK, "radau: restored");
    for (i = 0; i < 4 * nq; i++) s[i] = 0.0;     /* every node at the root, at rest */
    check(fp_radau_step(&e, &F, s, work, &iters, es) == FP_NONFINITE,
          "radau: no step from elements of no length");
    free(s); free(s1); free(work);
}

int main(int argc, char **argv)
{
    FILE *f;
    fp_plant p;
    int n, variant;
    if (argc != 2 || (f = fopen(argv[1], "r")) == NULL) return 2;
    check(fp_plant_abi() == FP_PLANT_ABI && fpf_abi() == FPF_ABI, "ABI versions");
    while (fscanf(f, "%d", &n) == 1) {
        memset(&p, 0, sizeof p);
        p.n = n;
        if (fscanf(f, "%lf %lf %lf %lf", &p.I0, &p.I1, &p.I2, &p.g) != 4) return 2;
        p.I3 = read_doubles(f, n);
        p.I5 = read_doubles(f, n);
        p.K = read_doubles(f, n);
        p.D = read_doubles(f, n);
        p.tip_slope = read_doubles(f, n);
        p.tip_defl = read_doubles(f, n);
        p.Kg = read_doubles(f, n * n);
        for (variant = 0; variant < 4; variant++) {
            p.linear = variant & 1;
            p.preload = (variant >> 1) & 1;
            check(fp_plant_prepare(&p) == FP_OK, "plant data accepted");
            plant_checks(&p);
        }
        free((void *)p.I3);
        free((void *)p.I5);
        free((void *)p.K);
        free((void *)p.D);
        free((void *)p.tip_slope);
        free((void *)p.tip_defl);
        free((void *)p.Kg);
    }
    fclose(f);
    p.n = -1;
    check(fp_plant_prepare(&p) == FP_BADARG, "negative n refused");
    filter_checks();
    exact_checks(1);
    exact_checks(3);
    exact_checks(8);
    radau_checks(1);
    radau_checks(3);
    radau_checks(8);
    printf("%s %d checks, %d failed\n", failures ? "FAILED" : "ok", checks, failures);
    return failures ? 1 : 0;
}
