/*
 * fm_me.h - the model-exchange master's integration loop in C
 * (orchestration/cosim/model_exchange.py's ModelExchangeMaster.run with master.solver = "radau"),
 * for FMI 2.0 Model Exchange FMUs that need no execution tool (the native FMUs).
 *
 * Contract
 * --------
 * - C99 plus libm. No global state, no allocation, no I/O, no threads: everything is in the
 *   fme_master and fme_unit structs and the arrays they point to, which the caller (Python,
 *   orchestration/cosim/compiled_me.py) owns and fills; the work arrays have the sizes
 *   fme_work_doubles() and fme_work_ints() give.
 * - The FMUs are loaded, instantiated, initialised and put in continuous-time mode by the caller
 *   (fmpy); this loop receives their instance pointers and the addresses of their FMI functions.
 *   One evaluation of the ODE makes the calls of the Python master's _set_point, in the same
 *   order: fmi2SetTime and fmi2SetContinuousStates on every unit, then, in evaluation order,
 *   the early inputs (fmi2SetReal) and the connected outputs (fmi2GetReal), then the late
 *   inputs; then fmi2GetDerivatives, fmi2GetEventIndicators or fmi2GetDirectionalDerivative.
 * - The integrator is scipy's Radau (Radau IIA of order 5, Hairer and Wanner's RADAU5 logic as
 *   scipy.integrate.Radau writes it) step for step: the same initial step, simplified Newton
 *   iteration on the transformed collocation system, error estimate, step control, Jacobian
 *   reuse and collocation dense output. The Jacobian is the Python master's exact one,
 *   dF/dz = A + B (I - S D)^-1 S C from the directional derivatives. The results agree with
 *   the Python master's to rounding (the LU factorisations and norms are summed in another
 *   order than LAPACK's), not bit for bit.
 * - After every accepted step: the event indicators at the new point; a sign change is located
 *   on the dense output by Brent's method (scipy's brentq, the Python master's tolerances), the
 *   output rows up to it are stored and fme_run returns FME_EVENT (the caller runs event mode
 *   and restarts the integrator with fme_restart). Otherwise every unit hears
 *   fmi2CompletedIntegratorStep: one asking to terminate returns FME_TERMINATE, one asking for
 *   event mode FME_STEP_EVENT (the caller runs event mode, the integrator goes on).
 * - Every FMI status above fmi2Warning ends the run with FME_FAILED and names the unit, the
 *   call, its status and its time (the caller raises the Python master's CoSimulationError).
 */
#ifndef FM_ME_H
#define FM_ME_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

#ifndef FME_API
#if defined(_WIN32)
#define FME_API __declspec(dllexport)
#else
#define FME_API __attribute__((visibility("default")))
#endif
#endif

/* Version of the binary interface below (structs, codes). Bump on any change. */
#define FME_ABI 2

/* Results of fme_run(), fme_start() and fme_restart(). */
#define FME_DONE 0         /* every output row is stored */
#define FME_FAILED 1       /* an FMI call returned a status above fmi2Warning: see fail_* */
#define FME_CHUNK 2        /* max_steps steps taken: call again */
#define FME_BADARG 3       /* the struct is inconsistent (nothing was done) */
#define FME_EVENT 4        /* an event indicator changed sign at t_event, states z_event */
#define FME_STEP_EVENT 5   /* fmi2CompletedIntegratorStep asked for event mode at t (state y) */
#define FME_TERMINATE 6    /* fmi2CompletedIntegratorStep of unit fail_unit asked to terminate */
#define FME_TOO_SMALL 7    /* the step fell below the spacing of the numbers at t */
#define FME_FINISHED 8     /* the integrator reached t_bound before the last output point */

/* The FMI calls, as reported in fail_call. */
#define FME_CALL_SET_TIME 1
#define FME_CALL_SET_X 2
#define FME_CALL_SET_REAL 3
#define FME_CALL_GET_REAL 4
#define FME_CALL_GET_DX 5
#define FME_CALL_GET_Z 6
#define FME_CALL_DD 7
#define FME_CALL_COMPLETED 8

/* The FMI 2.0 Model Exchange functions used (fmi2Component = void *, fmi2ValueReference =
 * unsigned int, fmi2Boolean = fmi2Status = int). */
typedef int (*fme_set_time_fn)(void *c, double t);
typedef int (*fme_set_x_fn)(void *c, const double *x, size_t n);
typedef int (*fme_get_x_fn)(void *c, double *x, size_t n);
typedef int (*fme_set_real_fn)(void *c, const unsigned int *vr, size_t n, const double *value);
typedef int (*fme_get_real_fn)(void *c, const unsigned int *vr, size_t n, double *value);
typedef int (*fme_dd_fn)(void *c, const unsigned int *unknown, size_t n_unknown,
                         const unsigned int *known, size_t n_known, const double *dv_known,
                         double *dv_unknown);
typedef int (*fme_completed_fn)(void *c, int no_set_state_prior, int *enter_event_mode,
                                int *terminate);

/* One FMU ("in": set by the caller). Its states are z[sx .. sx + nx), its connected outputs
 * y[sy .. sy + n_out), its inputs u[su .. su + n_in) (offsets: the units' sizes summed in
 * their order). */
typedef struct fme_unit {
    void *c;                          /* in: the fmi2Component */
    fme_set_time_fn set_time;         /* in */
    fme_set_x_fn set_x;               /* in */
    fme_get_x_fn get_dx;              /* in: fmi2GetDerivatives */
    fme_get_x_fn get_z;               /* in: fmi2GetEventIndicators */
    fme_set_real_fn set_real;         /* in */
    fme_get_real_fn get_real;         /* in */
    fme_dd_fn dd;                     /* in: fmi2GetDirectionalDerivative */
    fme_completed_fn completed;       /* in: fmi2CompletedIntegratorStep */
    int nx, nz, n_out, n_in;          /* in: states, event indicators, outputs, inputs */
    int n_early, n_late, n_rec, pad_; /* in: inputs set before / after its outputs; recorded */
    const unsigned int *state_vr;     /* in: (nx) */
    const unsigned int *der_vr;       /* in: (nx) */
    const unsigned int *out_vr;       /* in: (n_out) */
    const unsigned int *in_vr;        /* in: (n_in) */
    const unsigned int *early_vr;     /* in: (n_early) */
    const int *early_pos;             /* in: (n_early) the output (index in y) each reads */
    const unsigned int *late_vr;      /* in: (n_late) */
    const int *late_pos;              /* in: (n_late) */
    const unsigned int *rec_vr;       /* in: (n_rec) */
    double *rec_val;                  /* work: (n_rec) */
} fme_unit;

typedef struct fme_master {
    int n_units, nx, ny, nu;          /* in: units; sums of their nx, n_out, n_in */
    int nz, pad_;                     /* in: sum of their nz */
    fme_unit *units;                  /* in: (n_units) */
    const int *order;                 /* in: (n_units) evaluation order */
    const int *src_pos;               /* in: (nu) the output (index in y) each input reads */
    double rtol;                      /* in */
    const double *atol;               /* in: (nx) */
    double max_step;                  /* in */
    double t_bound;                   /* in: the stop time */
    double t0, interval;              /* in: output grid t0 + k interval */
    long long n_out;                  /* in: the last row's index */
    long long rows;                   /* in/out: rows stored */
    int n_cols, pad2_;                /* in: recorded columns (time excluded) */
    const int *col_unit;              /* in: (n_cols) */
    const int *col_index;             /* in: (n_cols) index among the unit's recorded */
    double *out;                      /* in: (n_out + 1) x (1 + n_cols) rows */
    double *work;                     /* in: (fme_work_doubles()) */
    int *iwork;                       /* in: (fme_work_ints()) */
    double *y;                        /* out: (nx) the states at t (a view into work) */
    double t;                         /* out: the integrator's time */
    double t_event;                   /* out: on FME_EVENT */
    double *z_event;                  /* out: (nx) on FME_EVENT, the states there (in work) */
    long long steps;                  /* out: accepted steps */
    long long evaluations;            /* out: right-hand sides */
    long long jacobians;              /* out: Jacobians */
    double min_step_used, max_step_used; /* out */
    int fail_unit;                    /* out: on FME_FAILED, FME_TERMINATE, FME_STEP_EVENT */
    int fail_call;                    /* out: FME_CALL_* */
    int fail_status;                  /* out: the fmi2Status */
    int pad3_;
    double fail_time;                 /* out */
    /* the integrator's state (work: set by fme_start and fme_restart) */
    double t_old, h_abs, h_abs_old, error_norm_old, newton_tol;
    int has_h_old, has_err_old, current_jac, lu_valid, has_sol, laid_out;
    double pt_t;                      /* work: the time the FMUs were last set to */
    int pt_valid, pad4_;              /* work: 1 if they are at (pt_t, the states kept) */
} fme_master;

FME_API int fme_abi(void);
FME_API const char *fme_source_digest(void);
FME_API size_t fme_sizeof_unit(void);
FME_API size_t fme_sizeof_master(void);
/* The sizes of m->work and m->iwork for the sizes set in m and its units. */
FME_API size_t fme_work_doubles(const fme_master *m);
FME_API size_t fme_work_ints(const fme_master *m);

/* Start at (t, z) (row 0 stored by the caller): the event indicators there, then the
 * integrator (the right-hand side, the initial step, the Jacobian). */
FME_API int fme_start(fme_master *m, double t, const double *z);
/* Restart the integrator at (t, z) after event mode, then the event indicators there. */
FME_API int fme_restart(fme_master *m, double t, const double *z);
/* Take at most max_steps steps, storing the output rows they cover. */
FME_API int fme_run(fme_master *m, long long max_steps);

#ifdef __cplusplus
}
#endif

#endif
