/*
 * fp_plant.h - the compiled kernel of the flexible inverted pendulum (the plant).
 *
 * The same equations as plant_fmu/dynamics.py (the readable numpy specification; docs/model.md
 * section 4): a cart of position x with an elastic beam hinged on it, floating frame of reference,
 * n cantilever modes. Generalised coordinates q = [x, phi, eta_1..eta_n]; the state is
 * x = [q, qd] (2 (n + 2) doubles); the input is the force on the cart F_c.
 *
 * Contract
 * --------
 * - Portable C99 plus libm. No global state, no allocation, no I/O: every function works on the
 *   data it is given, so any number of plants can be stepped concurrently from any threads.
 * - The model data (sizes and invariants) come in an fp_plant filled by the caller (in Python
 *   from plant_fmu/beam.py, the one source of the modes and invariants) and checked once by
 *   fp_plant_prepare(). Arrays it points to are owned by the caller and must outlive its use.
 * - Units are SI: m, rad, s, kg, N. Angles from the upward vertical, counter-clockwise.
 * - Arrays are contiguous doubles; matrices are row-major.
 * - Work buffers are passed in by the caller; their sizes are given by fp_work_size().
 * - Every function that can fail returns an FP_* code (FP_OK = 0). The loops never run
 *   unbounded: the fixed-step loop does exactly the substeps it is asked for and the adaptive loop
 *   stops at a cap on its accepted steps (FP_CAP), leaving a consistent state to continue from.
 * - A state that becomes non-finite stops a loop (FP_NONFINITE) with y left at the last finite
 *   state; no loop ever hands back NaN silently.
 */
#ifndef FP_PLANT_H
#define FP_PLANT_H

#ifdef __cplusplus
extern "C" {
#endif

/* Exported from the kernel's own library; a native FMU that links the sources defines FP_API
 * empty, so that it exports the FMI functions alone. */
#ifndef FP_API
#if defined(_WIN32)
#define FP_API __declspec(dllexport)
#else
#define FP_API __attribute__((visibility("default")))
#endif
#endif

/* Version of the binary interface below (structs, signatures, codes). Bump on any change. */
#define FP_PLANT_ABI 5

/* The largest n + 2 of the stiffened model (its rhs works on the stack). */
#define FP_STIFF_NQMAX 18

/* Return codes. */
#define FP_OK 0
#define FP_BADARG 1        /* an argument is out of its documented range (nothing was done) */
#define FP_NONFINITE 2     /* a substep produced a non-finite state: y is the last finite one */
#define FP_CAP 3           /* the adaptive loop reached its cap on steps before t_end */
#define FP_UNDERFLOW 4     /* the adaptive step fell below the minimum step */
#define FP_NOCONVERGE 5    /* the exact beam's Newton did not converge, or its matrix is singular */

/* Built-in methods of the fixed-step loop and of fp_builtin_tableau(). */
#define FP_EULER 0             /* explicit Euler (tableau) */
#define FP_RK4 1               /* classical Runge-Kutta (tableau) */
#define FP_DOPRI5 2            /* Dormand-Prince 5(4) (tableau with error weights, FSAL) */
#define FP_SYMPLECTIC_EULER 3  /* qd+ = qd + h qdd(q, qd), then q+ = q + h qd+ (no tableau) */

/* Layout of fp_outputs(): out[FP_OUT_*], then the n modal coordinates from FP_OUT_ETA on. */
#define FP_OUT_X 0             /* cart position x_o, m */
#define FP_OUT_XDOT 1          /* cart velocity, m/s */
#define FP_OUT_PHI_O 2         /* angle of the tip tangent phi_o, rad */
#define FP_OUT_OMEGA_O 3       /* its rate omega_o, rad/s */
#define FP_OUT_PHI 4           /* rotation of the floating frame phi, rad */
#define FP_OUT_TIP 5           /* transverse tip deflection N(L) eta, m */
#define FP_OUT_ENERGY 6        /* total energy T + V, J */
#define FP_OUT_ETA 7           /* first modal coordinate; FP_OUT_ETA + n doubles in all */

/* The plant: sizes, invariants (beam.py) and the model variant. Fill every field marked "in",
 * then call fp_plant_prepare() once; the fields marked "derived" are filled by it. */
typedef struct fp_plant {
    int n;                       /* in: cantilever modes kept, n >= 0 (0: rigid pendulum) */
    int linear;                  /* in: 0 nonlinear model, 1 linearised at the upright rest state */
    int preload;                 /* in: 1 adds the geometric stiffness Kg of the self-weight */
    double I0;                   /* in: total mass m + rhoA L, kg */
    double I1;                   /* in: int rhoA s ds, kg m */
    double I2;                   /* in: int rhoA s^2 ds, kg m^2 */
    double g;                    /* in: gravity, m/s^2 */
    const double *I3;            /* in: (n) int rhoA N ds */
    const double *I5;            /* in: (n) int rhoA s N ds */
    const double *K;             /* in: (n) modal stiffness omega_j^2 (the diagonal), 1/s^2 */
    const double *D;             /* in: (n) modal damping 2 zeta omega_j (the diagonal), 1/s */
    const double *Kg;            /* in: (n x n) geometric stiffness; may be NULL if preload = 0 */
    const double *tip_slope;     /* in: (n) N'(L), rad per unit modal coordinate */
    const double *tip_defl;      /* in: (n) N(L), m per unit modal coordinate */
    int nx;                      /* derived: state size 2 (n + 2) */
    double I3I3, I3I5, I5I5;     /* derived: dot products of I3 and I5 */
    /* The stiffened floating frame (dynamics.py, StiffenedPlantModel): the nonlinear model with
     * the preload (preload = 1, Kg) plus the foreshortening's kinetic energy over mass points
     * (u_p = 1/2 eta.G_p.eta). It needs linear = 0 and n + 2 <= FP_STIFF_NQMAX; the exact
     * Jacobians and output derivatives refuse it (FP_BADARG). */
    int stiffened;               /* in: 1 the stiffened model (0: the fields below are unused) */
    int npts;                    /* in: mass points P >= 1 */
    const double *pts;           /* in: P x (2 + n + n^2): s_p, m_p, N(s_p), G(s_p) row-major */
} fp_plant;

/* A Butcher tableau of an explicit method: A (stages x stages, strictly lower), B, C (stages);
 * E = B - B_hat (stages) for an embedded pair, else NULL. fsal: the last stage is f(y_new). */
typedef struct fp_tableau {
    int stages;
    const double *A;
    const double *B;
    const double *C;
    const double *E;
    int fsal;
} fp_tableau;

/* The input over an advance, as FMI's input derivatives: the force at time t is
 * u0 + du (t - tu) + d2u (t - tu)^2 / 2 (du = d2u = 0: held), N, N/s, N/s^2. */
typedef struct fp_input {
    double u0, du, d2u, tu;
} fp_input;

/* Options and state of the adaptive Dormand-Prince loop (the error control of
 * plant_fmu/integrators/rk.py, ExplicitRungeKutta._step_adaptive). */
typedef struct fp_adaptive {
    double rtol;                 /* in: relative tolerance, > 0 */
    const double *atol;          /* in: absolute tolerance, n_atol values, each > 0 */
    int n_atol;                  /* in: 1 (scalar) or nx (one per state component) */
    double max_step;             /* in: largest step (may be +inf) */
    double min_step;             /* in: smallest step (besides the floor of 10 ulp of t), >= 0 */
    long max_steps;              /* in: cap on the accepted steps of one call (>= 1) */
    double h_abs;                /* in/out: the proposed next step */
    long nfev, nsteps, nrejected;  /* out: added to by each call */
    double fail_h, fail_min_step;  /* out: the step and the minimum when FP_UNDERFLOW */
} fp_adaptive;

/* The ABI version FP_PLANT_ABI, and the sha256 (hex) of the sources the library was built from
 * (a string of 64 characters, or "unknown" when built without it). */
FP_API int fp_plant_abi(void);
FP_API const char *fp_plant_source_digest(void);

/* Check the "in" fields (sizes, non-NULL arrays, finite values) and fill the derived ones.
 * FP_OK or FP_BADARG. */
FP_API int fp_plant_prepare(fp_plant *p);

/* Doubles of work needed by the loops for a tableau of `stages` stages: (stages + 2) nx. */
FP_API long fp_work_size(const fp_plant *p, int stages);

/* The built-in tableau of method FP_EULER, FP_RK4 or FP_DOPRI5 (static data), or NULL. */
FP_API const fp_tableau *fp_builtin_tableau(int method);

/* dx = dx/dt at the state x with the force u (nonlinear or linear model as p->linear says).
 * x and dx have nx doubles and must not overlap. */
FP_API void fp_rhs(const fp_plant *p, const double *x, double u, double *dx);

/* The total energy T + V at x (the linear model: its quadratic form plus g I1), J. */
FP_API double fp_energy(const fp_plant *p, const double *x);

/* tip[0] = phi_o, tip[1] = omega_o at x. */
FP_API void fp_tip(const fp_plant *p, const double *x, double *tip);

/* Every output at x into out (FP_OUT_ETA + n doubles, layout FP_OUT_*). The energy is computed
 * only when want_energy is nonzero (else out[FP_OUT_ENERGY] is left untouched). */
FP_API void fp_outputs(const fp_plant *p, const double *x, int want_energy, double *out);

/* n_steps substeps of length h from time t (the input polynomial is evaluated at the stage times
 * (t - tu) + k h + c_i h), in place on y. method is FP_SYMPLECTIC_EULER (tab ignored) or any
 * explicit tableau (method ignored unless FP_SYMPLECTIC_EULER). work: fp_work_size() doubles.
 * *done = the substeps taken. FP_OK, FP_NONFINITE (y: the last finite state) or FP_BADARG. */
FP_API int fp_fixed_steps(const fp_plant *p, int method, const fp_tableau *tab, const fp_input *u,
                          double t, double h, long n_steps, double *y, double *work, long *done);

/* Adaptive Dormand-Prince 5(4) (tab: an FSAL tableau with error weights E of an embedded 4th-order
 * solution, e.g. the built-in FP_DOPRI5) from *t to t_end, in place on y; f holds f(t, y, u(t))
 * on entry and on exit (the first same as last stage); a->h_abs carries the proposed step from
 * call to call. *t is the time reached. Returns FP_OK (t_end reached), FP_CAP (a->max_steps steps
 * accepted before t_end: the state is consistent, another call continues exactly as one longer
 * call would), FP_UNDERFLOW (the step fell below the minimum; y, t, f: the last accepted step) or
 * FP_BADARG. The rejections of one step are bounded too: each shrinks the step by at least 10 %
 * until it underflows. work: fp_work_size(p, tab->stages) doubles. */
FP_API int fp_dopri_advance(const fp_plant *p, const fp_tableau *tab, const fp_input *u,
                            double *t, double t_end, double *y, double *f, fp_adaptive *a,
                            double *work);

/* ---- Jacobians and output derivatives (issue 24) ------------------------------------------
 * Exact (closed form) at any state, the same formulas as dynamics.py's jacobian_numpy and
 * output_jacobian_numpy: with M(q) qdd = f(q, qd, u), d qdd/dz = M^-1 (df/dz - (dM/dz) qdd), each
 * column's right-hand side formed by hand and solved by the Schur complement the rhs uses: O(n)
 * a column, with or without the preload, so O(n^2) for the whole Jacobian, the size of J. work: fp_jacobian_work_size(p) = 4 nx doubles
 * (any of these functions). Each returns FP_OK, FP_NONFINITE (a result is not finite; the outputs
 * are written but must not be used) or FP_BADARG (a NULL pointer, or the stiffened model, which
 * has none of them). */
FP_API long fp_jacobian_work_size(const fp_plant *p);

/* J = d(dx/dt)/dx (nx x nx, row-major) and, if b is not NULL, b = d(dx/dt)/du (nx) at x with the
 * force u (nonlinear or linear model, with or without the preload). Columns of x and x_dot are 0
 * (nothing depends on them). */
FP_API int fp_jacobian(const fp_plant *p, const double *x, double u, double *J, double *b,
                       double *work);

/* out = J v + b du (nx): the derivative of dx/dt along the state direction v and the force rate
 * du, without forming J (O(n); O(n^2) with the preload). */
FP_API int fp_jvp(const fp_plant *p, const double *x, double u, const double *v, double du,
                  double *out, double *work);

/* C = d(outputs)/dx ((FP_OUT_ETA + n) x nx, row-major) at x, in the layout of fp_outputs
 * (FP_OUT_*; the energy's row is its gradient). No output depends on the force. */
FP_API int fp_output_jacobian(const fp_plant *p, const double *x, double *C);

/* The first (d1) and second (d2) time derivatives of every output (FP_OUT_ETA + n doubles each,
 * layout FP_OUT_*) at x, with the force u and its rate du at that instant: d1 = C f(x, u),
 * d2 = d/dt (C(x) f(x, u)) = f^T H_k f + C (J f + b du), in closed form per output (the chain
 * rule of phi_o = phi + atan(N'(L) eta) and of omega_o, its rate). The energy's are those of the
 * power balance dE/dt = u x_dot - etad.D.etad (+ c (etad.Kg.eta - eta.Kg.etad) / 2 with the
 * preload: the power of Kg's skew part, 0 for a symmetric Kg; c = cos phi, 1 in the linear model),
 * exact because the equations are Lagrange's for the energies fp_energy sums. */
FP_API int fp_output_derivatives(const fp_plant *p, const double *x, double u, double du,
                                 double *d1, double *d2, double *work);

/* ---- The exact rung (issue 27): the geometrically exact beam on the cart ---------------------
 * The same equations as plant_fmu/exact.py (the numpy specification): ne ANCF cable elements
 * (cubic Hermite position and slope per node) hinged on the cart, Kelvin-Voigt damping with the
 * coefficient beta_kv, 5-point Gauss quadrature per element, and the fixed-step generalized-alpha
 * method (Arnold & Bruls form) with Newton on the accelerations and the analytic tangent.
 * Coordinates q = [x, r'_0 (2), r_1 (2), r'_1 (2), ..., r_ne, r'_ne] (nq = 4 ne + 3; the root's
 * position is (x, 0)); the integrator's state is s = [q, qd, qdd, a] (4 nq doubles).
 *
 * The Newton matrix M + b' (h^2 beta K + h gamma C) is banded (an element couples the 8
 * coordinates of its two nodes: half-bandwidth 7 whatever ne) but for the closed loop's force
 * row (the force depends on the cart and on the tip's slope): it is factored as a band with
 * partial pivoting (O(nq) work and storage) and the row's entries outside the band are added by
 * the Sherman-Morrison formula (one more band solve per factorisation). */
typedef struct fp_exact {
    int ne;                      /* in: elements, 1 <= ne <= 100000 */
    double L, EA, EI, rhoA;      /* in: length m, axial and bending stiffness N, N m^2, kg/m */
    double g;                    /* in: gravity, m/s^2 */
    double m;                    /* in: cart mass, kg (> 0) */
    double beta_kv;              /* in: Kelvin-Voigt coefficient 2 zeta / omega_1, s (>= 0) */
    double h;                    /* in: step, s (> 0) */
    double rho_inf;              /* in: spectral radius at infinite frequency, [0, 1] */
    double tol;                  /* in: Newton tolerance on the correction of qd, relative */
    int max_iter;                /* in: Newton iterations per step, >= 1 */
    int nq;                      /* derived: 4 ne + 3 */
    double le, am, af, gamma, beta, bp;  /* derived: element length, method parameters */
    double gw[5], gd1[20], gd2[20];  /* derived: Gauss weights (ds), Hermite d/ds, d2/ds2 */
    const double *modal;         /* in: the modal law's C_f blocks (fp_exact_modal), or NULL */
} fp_exact;

/* The force on the cart during a step, at the step's end: F = F0 - Q0 (kx x + kp phi_o +
 * kd omega_o) with phi_o, omega_o the tip tangent's angle and rate (Q0 = 0: a held force F0). */
typedef struct fp_exact_force {
    double F0, Q0, kx, kp, kd;
} fp_exact_force;

/* Check the "in" fields and fill the derived ones. FP_OK or FP_BADARG. */
FP_API int fp_exact_prepare(fp_exact *p);

/* The modal damping law on the exact beam (plant_fmu/exact.py's FrameModalDamping): in the frame
 * of the root tangent the beam's deformation d (the root slope's stretch, then u, w, u', w' per
 * node) is damped by 1/2 d_t^T C_f d_t, C_f = M_f Phi diag(2 zeta omega_k) Phi^T M_f from the
 * clamped straight beam's modes, bending and axial apart: C_f's axial block ((2 ne + 1)^2,
 * order d0, u_1, u'_1, u_2, ...) then its bending block ((2 ne)^2, order w_1, w'_1, ...),
 * row-major, fp_exact_modal_size doubles. fp_exact_modal computes them (Cholesky, then
 * Householder's tridiagonal form and the implicit QL iteration on L^-1 K_f L^-T) into C with
 * fp_exact_modal_work_size doubles of work; p prepared. With p->modal = C the forces carry the
 * law's force -G^T C_f d_t (not its tangent). FP_OK, FP_BADARG or FP_NOCONVERGE (a mass block
 * not positive definite, the QL iteration not converged). */
FP_API long fp_exact_modal_size(const fp_exact *p);
FP_API long fp_exact_modal_work_size(const fp_exact *p);
FP_API int fp_exact_modal(const fp_exact *p, double zeta, double *C, double *work);

/* Doubles of work for fp_exact_forces, fp_exact_start and fp_exact_steps. */
FP_API long fp_exact_work_size(const fp_exact *p);

/* M qdd = f(q, qd, u): f (nq) and, if K and C are not NULL, K = -df/dq and C = -df/dqd (nq x
 * nq, row-major, dense) at q, qd with the force u. Mass matrix M (nq x nq) if not NULL. FP_OK,
 * FP_NONFINITE or FP_BADARG. */
FP_API int fp_exact_forces(const fp_exact *p, const double *q, const double *qd, double u,
                           double *f, double *K, double *C, double *M, double *work);

/* The integrator's state s = [q, qd, qdd, a] from q, qd (s[0 .. 2 nq) on entry) with consistent
 * accelerations qdd = a = M^-1 f under the force law F. FP_OK, FP_NONFINITE or FP_BADARG. */
FP_API int fp_exact_start(const fp_exact *p, const fp_exact_force *F, double *s, double *work);

/* n_steps generalized-alpha steps of p->h in place on s under the force law F (the same law at
 * every step). *done = the steps taken, *iters += the Newton iterations. On failure s is the
 * state after the last step taken and the code says why: FP_BADARG (an argument, or a force law
 * that is not finite), FP_NONFINITE (a residual is not finite) or FP_NOCONVERGE (Newton did not
 * converge in max_iter iterations, or its matrix is singular). */
FP_API int fp_exact_steps(const fp_exact *p, const fp_exact_force *F, long n_steps, double *s,
                          double *work, long *done, long *iters);

/* ---- The exact rung's integrator: Radau IIA (three stages, order 5, L-stable) ----------------
 * plant_fmu/exact.py's RadauIIA: the unknowns are the stage accelerations W_i (i = 1..3),
 * V_i = v0 + h sum_j a_ij W_j, Q_i = q0 + h c_i v0 + h^2 sum_j (A^2)_ij W_j, M W_i = f(Q_i, V_i,
 * F_i); the step ends at the last stage. Simplified Newton with the tangent (and the force law's
 * gradient) at the predicted second stage, decoupled by the eigenvectors of A into one real band
 * system gamma^2 M + h gamma C + h^2 K and one complex mu^2 M + h mu C + h^2 K (gamma, mu the
 * eigenvalues of A^-1), each factored as a band with the force row by Sherman-Morrison as the
 * generalized-alpha step's. The integrator's state is s = [q, qd, qdd, jerk] (4 nq doubles): the
 * accelerations at the step's end and their rate, from which the next step's first guess is
 * extrapolated. p->rho_inf is not used. */

/* The force law of a Radau step at its three stages: F_i = F0[i] - sum_j Q[3 i + j] e_j with
 * e_j = kx x + kp phi_o + kd omega_o at stage j (Q = 0: the forces F0[i] given). */
typedef struct fp_radau_force {
    double F0[3], Q[9], kx, kp, kd;
} fp_radau_force;

/* Doubles of work for fp_radau_start and fp_radau_step (at least fp_exact_work_size's). */
FP_API long fp_radau_work_size(const fp_exact *p);

/* s = [q, qd, qdd, jerk] from q, qd (s[0 .. 2 nq) on entry): accelerations consistent with the
 * first stage's law at (q, qd), jerk 0. FP_OK, FP_NONFINITE or FP_BADARG. */
FP_API int fp_radau_start(const fp_exact *p, const fp_radau_force *F, double *s, double *work);

/* One Radau IIA step of p->h in place on s under the law F; *iters += the Newton iterations;
 * e (3 doubles, may be NULL) the stage errors e_j at the converged stages. On failure s is
 * unchanged and the code says why, as fp_exact_steps's. */
FP_API int fp_radau_step(const fp_exact *p, const fp_radau_force *F, double *s, double *work,
                         long *iters, double *e);

/* The outputs at the integrator's state s (its first 2 nq doubles, q and qd) into out, in the
 * layout FP_OUT_X .. FP_OUT_ENERGY of fp_outputs (FP_OUT_PHI: the root tangent's angle from the
 * upward vertical; FP_OUT_TIP: the tip's distance from the line of the root tangent, along its
 * normal b2; FP_OUT_ENERGY: T + V, kinetic, strain and the beam's weight from the root's height,
 * written only if want_energy; work: fp_exact_work_size doubles, may be NULL without the
 * energy). FP_OK, FP_NONFINITE (an output is not finite) or FP_BADARG. */
FP_API int fp_exact_outputs(const fp_exact *p, const double *s, int want_energy, double *out,
                            double *work);

#ifdef __cplusplus
}
#endif

#endif /* FP_PLANT_H */
