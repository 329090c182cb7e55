/*
 * fm_adaptive.h - the compiled adaptive and implicit loops of the co-simulation master
 * (orchestration/cosim/master.py's Master._run_adaptive; orchestration/cosim/implicit.py's
 * InterfaceIteration stepped by Master._run_fixed), for FMI 2.0 co-simulation FMUs that need no
 * execution tool (the native FMUs). Bound in orchestration/cosim/compiled_adaptive.py.
 *
 * Contract
 * --------
 * - C99 plus libm. No global state, no allocation, no I/O, no threads: everything is in the
 *   fa_master and fa_slave structs and the arrays they point to, which the caller owns and fills.
 * - The FMUs are loaded, instantiated and initialised by the caller (fmpy); this loop receives
 *   their instance pointers and FMI functions and makes the calls the Python loop makes, in the
 *   same order, with the same arguments (rollback through getFMUstate/setFMUstate included).
 * - The arithmetic is the Python loop's, operation for operation (-ffp-contract=off, pow as
 *   Python's **, sums left to right), except for one thing: the extrapolation weights on the
 *   adaptive grid solve a Vandermonde system of 1 to 3 nodes, which numpy does with LAPACK
 *   (OpenBLAS, whose kernels' order and fused multiply-adds depend on the CPU) and this loop with
 *   its own Gaussian elimination with partial pivoting: the weights agree to a few units in the
 *   last place, not bit for bit (tests/cosim/test_compiled_adaptive.py holds the runs together).
 *   The implicit loop steps on the step counters' grid with the Python master's own weights
 *   (coupling.weight_table); its linear algebra differs: Newton's (J - I) x = r by Gaussian
 *   elimination with partial pivoting (numpy: LAPACK), IQN-ILS's least squares by a one-sided
 *   Jacobi SVD with numpy's cut-off (numpy: LAPACK's gelsd).
 * - Every FMI status above fmi2Warning ends the run with FA_FAILED naming the slave, the call, its
 *   status and its time, except fmi2Discard during a step with the extrapolation estimator,
 *   which rolls the step back and retries it at half the step (FA_DISCARDED when that happens at
 *   min_step), as in Python.
 */
#ifndef FM_ADAPTIVE_H
#define FM_ADAPTIVE_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

#ifndef FA_API
#if defined(_WIN32)
#define FA_API __declspec(dllexport)
#else
#define FA_API __attribute__((visibility("default")))
#endif
#endif

/* Version of the binary interface below (structs, codes). Bump on any change. */
#define FA_ABI 5

/* Results of fa_run(). */
#define FA_DONE 0       /* the output points up to j_end are reached */
#define FA_FAILED 1     /* an FMI call returned a status above fmi2Warning: see fail_* */
#define FA_STOPPED 2    /* the stop callback asked to stop after the step ending at t_reached */
#define FA_BADARG 3     /* the struct is inconsistent (nothing was done) */
#define FA_DISCARDED 4  /* an FMU discarded the step at fail_time even at min_step */
#define FA_FULL 5       /* the rejected_times buffer is full: drain it (n_rej = 0), call again */
#define FA_DIVERGED 6   /* implicit: the interface did not converge: see fail_kind */

/* Why an implicit step failed (fail_kind with FA_DIVERGED). */
#define FA_NOT_CONVERGED 1  /* max_iterations evaluations; fail_residual the last residual */
#define FA_NOT_FINITE 2     /* an output is not finite after fail_iterations evaluations */
#define FA_SINGULAR 3       /* Newton: J - I is singular; fail_residual the residual */

/* IQN-ILS: the steps whose difference columns are reused (implicit.py REUSED_STEPS). */
#define FA_REUSED_STEPS 8

/* The FMI calls, as reported in fail_call (the numbers of fm_master.h). */
#define FA_CALL_SET_REAL 1
#define FA_CALL_SET_DER 2
#define FA_CALL_DO_STEP 3
#define FA_CALL_GET_REAL 4
#define FA_CALL_GET_STATE 5
#define FA_CALL_SET_STATE 6
#define FA_CALL_FREE_STATE 7

/* History depth of every signal, and its slots (one more for a provisional sample). */
#define FA_DEPTH 3
#define FA_SLOTS 4

typedef int (*fa_set_real_fn)(void *c, const unsigned int *vr, size_t n, const double *value);
typedef int (*fa_get_real_fn)(void *c, const unsigned int *vr, size_t n, double *value);
typedef int (*fa_do_step_fn)(void *c, double t, double h, int no_set_state_prior);
typedef int (*fa_set_der_fn)(void *c, const unsigned int *vr, size_t n, const int *order,
                             const double *value);
typedef int (*fa_get_state_fn)(void *c, void **state);
typedef int (*fa_set_state_fn)(void *c, void *state);
typedef int (*fa_free_state_fn)(void *c, void **state);
/* Asked after every accepted step: nonzero to go on, 0 to stop. */
typedef int (*fa_go_on_fn)(void);

/* One FMU. "in": set by the caller; "work": buffers of the given sizes; "in/out": its history
 * and error scales, set by the caller before the first call and kept up to date. */
typedef struct fa_slave {
    void *c;                          /* in: the fmi2Component */
    fa_set_real_fn set_real;          /* in */
    fa_get_real_fn get_real;          /* in */
    fa_do_step_fn do_step;            /* in */
    fa_set_der_fn set_der;            /* in: needed when n_der > 0 */
    fa_get_state_fn get_state;        /* in: needed for rollback and the corrected first step */
    fa_set_state_fn set_state;        /* in: same */
    fa_free_state_fn free_state;      /* in: same */
    int n_in;                         /* in: real inputs fed by connections */
    int n_der;                        /* in: input derivative orders passed (0, 1, 2) */
    int n_out;                        /* in: real outputs feeding connections */
    int n_rec;                        /* in: real outputs only recorded */
    int feedthrough;                  /* in: outputs may depend directly on inputs */
    int mark;                         /* work */
    int at_start;                     /* work: implicit: not stepped since its state was taken */
    int unknown;                      /* in: implicit: its outputs are unknowns of the interface */
    const unsigned int *in_vr;        /* in: (n_in) */
    const int *in_src;                /* in: (n_in) source slave of each input */
    const int *in_idx;                /* in: (n_in) index among the source's outputs */
    const unsigned int *der_vr;       /* in: (n_in n_der) inputs, repeated per order */
    const int *der_order;             /* in: (n_in n_der) 1..., then 2... */
    const unsigned int *out_vr;       /* in: (n_out) */
    const unsigned int *rec_vr;       /* in: (n_rec) */
    double *in_val;                   /* work: (n_in) */
    double *der_val;                  /* work: (n_in n_der) */
    double *new_val;                  /* work: (n_out) the outputs at the end of the step */
    double *rec_val;                  /* work: (n_rec) */
    double *saved;                    /* work: (n_out) */
    double *hist;                     /* in/out: (FA_SLOTS n_out) samples, oldest first */
    double *snap;                     /* work: (FA_SLOTS n_out) the history before a step */
    double *peak;                     /* in/out: (n_out) the outputs' largest magnitudes */
    double *peak_saved;               /* work: (n_out) */
    double t[FA_SLOTS];               /* in/out: the samples' times (seconds) */
    double snap_t[FA_SLOTS];          /* work */
    int count;                        /* in/out: samples in hist (1..FA_DEPTH) */
    int snap_count;                   /* work */
    void *state;                      /* work: the corrected first step's FMU state */
    void *rb_state;                   /* work: the rollback's FMU state */
} fa_slave;

typedef struct fa_master {
    int n_slaves;                     /* in */
    int gauss_seidel;                 /* in: 1 Gauss-Seidel, 0 Jacobi */
    int p;                            /* in: extrapolation order 0, 1, 2 */
    int correct_startup;              /* in: predict and correct the first step */
    int rollback;                     /* in: 1 estimator "extrapolation", 0 "energy" */
    int n_sources;                    /* in: slaves whose outputs feed connections */
    fa_slave *slaves;                 /* in: (n_slaves), in the order of their dict */
    const int *order;                 /* in: (n_slaves) coupling order */
    const int *sources;               /* in: (n_sources) in the connections' order */
    double t0;                        /* in: start time */
    double h;                         /* in: master.step (the scale of the error estimates) */
    double dt_out;                    /* in: output interval */
    double tol;                       /* in: master.tolerance */
    double min_step, max_step;        /* in */
    long long n_out;                  /* in: output points after t0 */
    int f_slave, f_idx;               /* in: energy: the force's source and output index */
    int x_slave, x_idx;               /* in: energy: the position's source and output index */
    int f_pred;                       /* in: energy: the force is extrapolated too */
    int n_cols;                       /* in: recorded columns (time excluded) */
    const int *col_slave;             /* in: (n_cols) */
    const int *col_rec;               /* in: (n_cols) 1 if from the recorded-only variables */
    const int *col_index;             /* in: (n_cols) */
    double *out;                      /* in: (n_out + 1) x (1 + n_cols) rows */
    fa_go_on_fn go_on;                /* in: NULL, or asked after every accepted step */
    double *rejected_times;           /* in: (rej_cap) the start times of rejected steps */
    long long rej_cap;                /* in */
    long long n_rej;                  /* in/out: entries in rejected_times */
    long long j;                      /* in/out: the next output point (1 at the start) */
    double t;                         /* in/out: the time reached (t0 at the start) */
    double step;                      /* in/out: the step the controller chose */
    double err_prev;                  /* in/out: the PI controller's previous error (1) */
    double work;                      /* in/out: energy: the work through the bond (0) */
    long long steps, rejected, forced;  /* out: accepted, rejected, forced steps */
    double min_used, max_used;        /* out: the smallest and largest accepted steps */
    long long rows;                   /* in/out: rows stored */
    /* the step counters' grid (fixed step; the implicit loop) */
    int counters;                     /* in: 1: samples stamped k, at t0 + k h (0: seconds) */
    int newton;                       /* in: implicit: 1 Newton, 0 IQN-ILS */
    int serial;                       /* in: implicit: 1 the serial scheme, 0 the parallel */
    const double *weights;            /* in: coupling.weight_table() [3][3][4][3] */
    long long total;                  /* in: implicit: steps of the run */
    long long m_out;                  /* in: implicit: steps per output interval */
    long long k;                      /* in/out: implicit: steps taken */
    int max_it;                       /* in: master.max_iterations */
    int size;                         /* in: the interface's unknowns (the exchanged outputs) */
    double itol;                      /* in: master.implicit_tolerance */
    const int *consumer;              /* in: (n_slaves n_slaves) [src][dst] 1 if dst reads src */
    double *u, *g, *r, *up, *col, *x; /* work: (size) each */
    double *lu, *lg;                  /* work: (size) each: Newton's previous u and g */
    double *jac;                      /* in/out: (size size) Newton's dG/du, kept across steps */
    double *a;                        /* work: (size size) */
    int have_jac;                     /* in/out: jac holds a Jacobian */
    int n_reuse;                      /* in/out: IQN-ILS: past steps whose columns are kept */
    int reuse_cols[FA_REUSED_STEPS];  /* in/out: their column counts, oldest first */
    int max_cols;                     /* in: (FA_REUSED_STEPS + 1) max_it */
    double *cv, *cw;                  /* in/out: (max_cols size) columns V, W: reused, then the
                                       * step's */
    double *svd_m, *svd_v, *alpha;    /* work: (size max_cols), (size size), (max_cols) */
    long long iterations;             /* out: implicit: iterations summed over the steps */
    int max_iterations;               /* out: the most in one step */
    int fail_kind;                    /* out: FA_DIVERGED: FA_NOT_CONVERGED... */
    long long jacobian_steps;         /* out: FMU steps spent on difference Jacobians */
    double fail_residual;             /* out: FA_DIVERGED: the residual (times itol) */
    int fail_iterations;              /* out: FA_DIVERGED: the evaluations made */
    int pad_;
    int fail_slave;                   /* out: on FA_FAILED */
    int fail_call;                    /* out: FA_CALL_* */
    int fail_status;                  /* out: the fmi2Status */
    int fail_timed;                   /* out: 1 if fail_time applies */
    double fail_time;                 /* out */
    double pow_arg, pow1, pow2;       /* work: the held inputs' scale and its powers 1 and 2
                                       * (libm's pow, as Python's **), for the next fill at the
                                       * same scale; 0 before the first (set 0 by the caller) */
} fa_master;

FA_API int fa_abi(void);
FA_API const char *fa_source_digest(void);
FA_API size_t fa_sizeof_slave(void);
FA_API size_t fa_sizeof_master(void);
/* Python's round(x, 9) (correctly rounded, ties to even), as the Python loop rounds its nodes. */
FA_API double fa_round9(double x);
/* The weights of the polynomial through the n (1..3) nodes tau: its average over [0, 1]
 * (kind -1) or its kind-th derivative at 0 (kind 0, 1, 2), into w; 0 if the system is
 * singular. */
FA_API int fa_weights(const double *tau, int n, int kind, double *w);
/* Step until output point j_end (at most n_out) is reached. */
FA_API int fa_run(fa_master *m, long long j_end);
/* Implicit: take steps m->k .. k_end - 1 (at most m->total), storing a row every m_out steps
 * and asking go_on after every step. */
FA_API int fa_run_implicit(fa_master *m, long long k_end);

#ifdef __cplusplus
}
#endif

#endif
