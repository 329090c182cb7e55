/*
 * fm_master.h - the compiled fixed-step loop of the co-simulation master
 * (orchestration/cosim/master.py's Master.run with adaptive = false), for FMI 2.0 co-simulation FMUs
 * that need no execution tool (the native FMUs).
 *
 * Contract
 * --------
 * - C99 plus libm. No global state, no allocation, no I/O, no threads: everything is in the
 *   fm_master and fm_slave structs and the arrays they point to, which the caller (Python,
 *   orchestration/cosim/compiled.py) owns and fills.
 * - The FMUs are loaded, instantiated and initialised by the caller (fmpy); this loop receives
 *   their instance pointers and the addresses of their FMI functions, and makes only the calls
 *   the Python loop makes, in the same order, with the same arguments.
 * - The arithmetic is the Python master's, operation for operation: the extrapolation weights
 *   come from Python (the same cached solutions of the same Vandermonde systems), the
 *   derivative rows are divided by pow(h, order) as numpy divides them, and the combinations
 *   are summed left to right with no contraction (compiled with -ffp-contract=off), as the
 *   Python master sums them. The results are bit-identical.
 * - The time grid is t0 + k h from integers, as in Python: the FMUs step from t0 + k h over h,
 *   and the extrapolation nodes are the offsets of the samples' step indices, integers however
 *   long the run (the Python loop stamps its history with the step counters too).
 * - Every FMI status above fmi2Warning ends the run with FM_FAILED and names the slave, the call,
 *   its status and its time (the caller raises the Python master's CoSimulationError).
 */
#ifndef FM_MASTER_H
#define FM_MASTER_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

#ifndef FM_API
#if defined(_WIN32)
#define FM_API __declspec(dllexport)
#else
#define FM_API __attribute__((visibility("default")))
#endif
#endif

/* Version of the binary interface below (structs, codes). Bump on any change. */
#define FM_ABI 5

/* Results of fm_run(). */
#define FM_DONE 0       /* the steps up to k_end are taken */
#define FM_FAILED 1     /* an FMI call returned a status above fmi2Warning: see fail_* */
#define FM_STOPPED 2    /* the stop callback asked to stop after step k */
#define FM_BADARG 3     /* the struct is inconsistent (nothing was done) */

/* The FMI calls, as reported in fail_call. */
#define FM_CALL_SET_REAL 1       /* fmi2SetReal (inputs) */
#define FM_CALL_SET_DER 2        /* fmi2SetRealInputDerivatives */
#define FM_CALL_DO_STEP 3        /* fmi2DoStep */
#define FM_CALL_GET_REAL 4       /* fmi2GetReal (outputs, or recorded variables) */
#define FM_CALL_GET_STATE 5      /* fmi2GetFMUstate */
#define FM_CALL_SET_STATE 6      /* fmi2SetFMUstate */
#define FM_CALL_FREE_STATE 7     /* fmi2FreeFMUstate */
#define FM_CALL_GET_DER 8        /* fmi2GetRealOutputDerivatives */

/* History depth of every signal (samples kept; one more slot for the Gauss-Seidel update). */
#define FM_DEPTH 3
#define FM_SLOTS 4

/* The FMI 2.0 functions used (fmi2Component = void *, fmi2ValueReference = unsigned int,
 * fmi2Integer = fmi2Boolean = fmi2Status = int, fmi2FMUstate = void *). */
typedef int (*fm_set_real_fn)(void *c, const unsigned int *vr, size_t n, const double *value);
typedef int (*fm_get_real_fn)(void *c, const unsigned int *vr, size_t n, double *value);
typedef int (*fm_do_step_fn)(void *c, double t, double h, int no_set_state_prior);
typedef int (*fm_set_der_fn)(void *c, const unsigned int *vr, size_t n, const int *order,
                             const double *value);
typedef int (*fm_get_der_fn)(void *c, const unsigned int *vr, size_t n, const int *order,
                             double *value);
typedef int (*fm_get_state_fn)(void *c, void **state);
typedef int (*fm_set_state_fn)(void *c, void *state);
typedef int (*fm_free_state_fn)(void *c, void **state);
/* Asked after every step: nonzero to go on, 0 to stop (a Python callback that raises gives 0). */
typedef int (*fm_go_on_fn)(void);

/* One FMU. "in": set by the caller; "work": buffers of the given sizes; "in/out": the state of
 * its history, set by the caller before the first call and kept up to date. A sample of its
 * signals is its n_out outputs followed, with n_oder > 0, by their time derivatives of orders
 * 1..n_oder (fmi2GetRealOutputDerivatives; block per order): n_out (1 + n_oder) values, the
 * "width" below; the extrapolation of such a source is the Taylor polynomial at its newest
 * sample (Master._combination). */
typedef struct fm_slave {
    void *c;                          /* in: the fmi2Component */
    fm_set_real_fn set_real;          /* in */
    fm_get_real_fn get_real;          /* in */
    fm_do_step_fn do_step;            /* in */
    fm_set_der_fn set_der;            /* in: needed when n_der > 0 */
    fm_get_state_fn get_state;        /* in: needed when the master corrects the first step */
    fm_set_state_fn set_state;        /* in: same */
    fm_free_state_fn free_state;      /* in: same */
    fm_get_der_fn get_der;            /* in: needed when n_oder > 0 */
    int n_in;                         /* in: real inputs fed by connections */
    int n_der;                        /* in: input derivative orders passed (0, 1, 2) */
    int n_out;                        /* in: real outputs feeding connections */
    int n_rec;                        /* in: real outputs only recorded */
    int n_oder;                       /* in: output derivative orders read (0, 1, 2; up to 4
                                       * with hermite) */
    int feedthrough;                  /* in: outputs may depend directly on inputs */
    int sampled;                      /* in: a sampled controller (Master: its outputs are read
                                       * with its inputs at the others' new outputs) */
    const unsigned int *in_vr;        /* in: (n_in) */
    const int *in_src;                /* in: (n_in) source slave of each input */
    const int *in_idx;                /* in: (n_in) index among the source's outputs */
    const unsigned int *der_vr;       /* in: (n_in n_der) inputs, repeated per order */
    const int *der_order;             /* in: (n_in n_der) 1..., then 2... */
    const unsigned int *out_vr;       /* in: (n_out) */
    const unsigned int *rec_vr;       /* in: (n_rec) */
    const unsigned int *oder_vr;      /* in: (n_out n_oder) outputs, repeated per order */
    const int *oder_order;            /* in: (n_out n_oder) 1..., then 2... */
    double *in_val;                   /* work: (n_in) */
    double *der_val;                  /* work: (n_in n_der) */
    double *new_val;                  /* work: (width) the sample at the end of the step */
    double *rec_val;                  /* work: (n_rec) */
    double *saved;                    /* work: (width) */
    double *hist;                     /* in/out: (FM_SLOTS width) samples, oldest first */
    long long newest;                 /* in/out: step index of the newest sample */
    int count;                        /* in/out: samples in hist (1..FM_DEPTH) */
    int mark;                         /* work */
    void *state;                      /* work */
} fm_slave;

typedef struct fm_master {
    int n_slaves;                     /* in */
    int gauss_seidel;                 /* in: 1 Gauss-Seidel, 0 Jacobi */
    int p;                            /* in: extrapolation order 0, 1, 2 */
    int correct_startup;              /* in: predict and correct the first step */
    fm_slave *slaves;                 /* in: (n_slaves), in the order of their dict */
    const int *order;                 /* in: (n_slaves) coupling order (Gauss-Seidel: first...) */
    double t0;                        /* in: start time */
    double h;                         /* in: communication step */
    long long total;                  /* in: steps of the run */
    long long m;                      /* in: steps per output interval */
    const double *weights;            /* in: [3: newest node -1, 0, 1][3: nodes 1..3]
                                             [4: average, value, 1st, 2nd derivative][3] */
    int n_cols;                       /* in: recorded columns (time excluded) */
    int pad_;
    const int *col_slave;             /* in: (n_cols) */
    const int *col_rec;               /* in: (n_cols) 1 if from the recorded-only variables */
    const int *col_index;             /* in: (n_cols) index in outputs or recorded variables */
    double *out;                      /* in: (total / m + 1) x (1 + n_cols) rows */
    fm_go_on_fn go_on;                /* in: NULL, or asked after every step */
    long long k;                      /* in/out: steps taken */
    long long rows;                   /* in/out: rows stored */
    int fail_slave;                   /* out: on FM_FAILED */
    int fail_call;                    /* out: FM_CALL_* */
    int fail_status;                  /* out: the fmi2Status */
    int fail_timed;                   /* out: 1 if fail_time applies (0: the state calls) */
    double fail_time;                 /* out */
    double dweights[3][3][2][3];      /* work: the derivative rows of weights (nodes, newest
                                       * node -1, 0, 1; 1st, 2nd), divided by h, h^2 */
    double taylor[3][4][5];           /* work: the Taylor rows from (newest node) h seconds
                                       * before the sample, per kind (average, value, 1st,
                                       * 2nd derivative), on [y, y', ..., y''''] */
    int hermite;                      /* in: the Hermite coupling (Coupling.hermite; Gauss-Seidel) */
    int pad2_;
    const double *hweights;           /* in (hermite): hermite_rows(q, two_point, h) as
                                       * [q - 1: 0..3][two_point: 0, 1][4: average, value, 1st,
                                       * 2nd derivative][10: its 2 (q + 1) or q + 1 weights] */
} fm_master;

FM_API int fm_abi(void);
FM_API const char *fm_source_digest(void);
FM_API size_t fm_sizeof_slave(void);
FM_API size_t fm_sizeof_master(void);

/* Take steps m->k .. k_end - 1 (at most m->total), storing a row at every multiple of m->m and
 * asking m->go_on after every step. Returns FM_DONE, FM_FAILED, FM_STOPPED or FM_BADARG; m->k
 * and m->rows say how far it got. */
FM_API int fm_run(fm_master *m, long long k_end);

#ifdef __cplusplus
}
#endif

#endif
