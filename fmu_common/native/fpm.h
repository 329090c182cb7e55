/*
 * fpm.h - the native FMUs' instance core, version-neutral, and what a model gives it.
 *
 * The shape of the Modelica Reference-FMUs (src/cosimulation.c under fmi2Functions.c and
 * fmi3Functions.c), our own code, in three layers:
 *
 *   the guard (fpm_guard.c)  the mode machine (one bit per mode, a mask per call), the checks of
 *                            value references, types, causalities and arrays against the model's
 *                            generated table of variables, and the log line of every non-OK
 *                            status. It needs no model: the pythonfmu FMUs' loader
 *                            (fmu_common/loader/fmi2_loader.c) checks its calls with it too.
 *   the core (fpm_core.c)    one instance: life cycle, variable access through the table, doStep's
 *                            checks, FMU states (copy, serialisation, restore: only independent
 *                            quantities are saved; a restore validates everything and rebuilds
 *                            the derived ones with the code initialisation uses, into a spare
 *                            model, so that a failed restore changes nothing).
 *   the adapters             fmi2.c and fmi3.c: signatures, status codes and each call's mask.
 *
 * A model (plant_model.c, controller_model.c) gives
 *   - its table of variables, generated at build time from the Python table of the model
 *     (plant_fmu/interface.py, controller_fmu/interface.py) into fpm_vars.h;
 *   - its data, one struct (fpm_model) holding the values of the table and its own state;
 *   - its parameter checks (fpm_model_init), its step (fpm_model_step), its outputs, and the
 *     save and load of its independent state (fpm_model_save, fpm_model_load).
 * Model Exchange (the next interface) adds its modes (FPM_CONTINUOUS) and the model's
 * right-hand side to this core; the mode machine, the table checks and the states stay.
 *
 * Contract: C99 plus libm; no global mutable state (every instance is its own memory); no
 * allocation after instantiation except for FMU states the host asks for; every non-OK status
 * is returned together with a log message naming its cause (fpm_log).
 */
#ifndef FPM_H
#define FPM_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* statuses (the values of fmi2Status and fmi3Status for OK .. Fatal) */
#define FPM_OK 0
#define FPM_WARNING 1
#define FPM_DISCARD 2
#define FPM_ERROR 3
#define FPM_FATAL 4

/* variable types and causalities of the table */
#define FPM_REAL 0
#define FPM_INTEGER 1
#define FPM_BOOLEAN 2
#define FPM_STRING 3
#define FPM_PARAMETER 0
#define FPM_INPUT 1
#define FPM_OUTPUT 2
#define FPM_LOCAL 3           /* Model Exchange: a state that is no output, a derivative, an
                                 event indicator (read only) */

#define FPM_MAX_VARS 96       /* value references 0 .. FPM_MAX_VARS - 1 */
#define FPM_STR_MAX 32        /* longest string value, with its terminating 0 */
#define FPM_MSG_MAX 512       /* longest log message */

/* Relative tolerance on the communication point of doStep against the model's own time (the
 * pythonfmu slaves' TIME_RTOL). */
#define FPM_TIME_RTOL 1e-9

/* ---- The mode machine ------------------------------------------------------------------- */
/* One bit per mode, for every FMI version and interface; each call of an adapter names the
 * modes it is allowed in (a mask). */
#define FPM_INSTANTIATED 1
#define FPM_INIT 2            /* initialization mode */
#define FPM_EVENT 4           /* event mode (FMI 3.0; Model Exchange) */
#define FPM_CONTINUOUS 8      /* continuous-time mode (Model Exchange) */
#define FPM_STEP 16           /* step mode (FMI 2.0: stepComplete) */
#define FPM_TERMINATED 32
#define FPM_ERROR_MODE 64     /* after a failed exitInitializationMode */
#define FPM_ANY 127
#define FPM_FATAL_MODE 128    /* unusable (the pythonfmu loader: pythonfmu's instance broke):
                                 in no mask, only freeInstance */

/* Model Exchange (FMI 2.0 section 3.2.3, FMI 3.0 section 3.2): the modes of its calls. */
#define FPM_ME_MASK_SET_TIME (FPM_EVENT | FPM_CONTINUOUS)
#define FPM_ME_MASK_SET_STATES FPM_CONTINUOUS
#define FPM_ME_MASK_GET_DERIVATIVES (FPM_INIT | FPM_EVENT | FPM_CONTINUOUS | FPM_TERMINATED | \
                                     FPM_ERROR_MODE)
#define FPM_ME_MASK_GET_STATES (FPM_INIT | FPM_EVENT | FPM_CONTINUOUS | FPM_TERMINATED | \
                                FPM_ERROR_MODE)
#define FPM_ME_MASK_NEW_DISCRETE FPM_EVENT
#define FPM_ME_MASK_ENTER_EVENT (FPM_EVENT | FPM_CONTINUOUS)
#define FPM_ME_MASK_ENTER_CONTINUOUS FPM_EVENT
#define FPM_ME_MASK_COMPLETED_STEP FPM_CONTINUOUS
#define FPM_ME_MASK_TERMINATE (FPM_EVENT | FPM_CONTINUOUS | FPM_ERROR_MODE)
#define FPM_ME_MASK_SET (FPM_INSTANTIATED | FPM_INIT | FPM_EVENT | FPM_CONTINUOUS)

/* FMI 2.0 co-simulation: the modes each call is allowed in (the standard's table of section
 * 4.2.4), shared by fmi2.c and the pythonfmu loader. */
#define FPM2_MASK_ANY FPM_ANY
#define FPM2_MASK_SETUP FPM_INSTANTIATED
#define FPM2_MASK_ENTER_INIT FPM_INSTANTIATED
#define FPM2_MASK_EXIT_INIT FPM_INIT
#define FPM2_MASK_TERMINATE (FPM_STEP | FPM_ERROR_MODE)
#define FPM2_MASK_RESET FPM_ANY
#define FPM2_MASK_GET FPM_ANY
#define FPM2_MASK_SET (FPM_INSTANTIATED | FPM_INIT | FPM_STEP)
#define FPM2_MASK_STATE FPM_ANY
#define FPM2_MASK_DO_STEP FPM_STEP
/* parameters (variability fixed) may be set in these modes only */
#define FPM_MASK_SET_PARAMETER (FPM_INSTANTIATED | FPM_INIT)

/* Interfaces */
#define FPM_COSIMULATION 0
#define FPM_MODEL_EXCHANGE 1

/* One variable of the table (generated into fpm_vars.h). */
typedef struct fpm_var {
    const char *name;
    int type;                 /* FPM_REAL .. FPM_STRING */
    int causality;            /* FPM_PARAMETER, FPM_INPUT, FPM_OUTPUT */
    double start_real;        /* start of a Real, Integer (exact) or Boolean (0/1) */
    const char *start_string; /* start of a String */
    int state;                /* 1 + its index among the continuous states, or 0 */
    int der;                  /* 1 + the index of the state it is the derivative of, or 0 */
    int indicator;            /* 1 + its index among the event indicators, or 0 */
} fpm_var;

/* The values of the parameters and inputs, indexed by value reference. */
typedef struct fpm_values {
    double real[FPM_MAX_VARS];           /* Real, Integer and Boolean values */
    char string[FPM_MAX_VARS][FPM_STR_MAX];
} fpm_values;

/* A logger: where the messages of one instance go. */
typedef struct fpm_logger {
    void (*emit)(void *env, int status, const char *category, const char *message);
    void *env;
} fpm_logger;

/* The log categories (native_fmus.LOG_CATEGORIES), indexed by the status whose messages they
 * are: a message of status s has category fpm_log_categories[s] (FPM_OK: "logAll", the debug
 * messages; "logAll" enabled also lets every other category's messages through). */
#define FPM_N_CATEGORIES 5
extern const char *const fpm_log_categories[FPM_N_CATEGORIES];
/* The index of category `name` in fpm_log_categories, or -1 (not one of them; NULL). */
int fpm_log_category(const char *name);

/* Format and send a message with a status (a printf format; '%' is never sent on). */
void fpm_log(const fpm_logger *lg, int status, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

/* The table of the model (generated). */
extern const fpm_var fpm_vars[FPM_MAX_VARS];   /* name NULL: no variable of that reference */
extern const char fpm_model_name[];
extern const char fpm_token[];                 /* GUID / instantiation token */
extern const long fpm_time_vr;                 /* FMI 3.0's independent variable `time` (not in
                                                  fpm_vars: FMI 2.0 does not declare it), -1 if
                                                  the table has none */

/* ---- The guard (fpm_guard.c): no model needed --------------------------------------------- */
/* The name of a mode ("Instantiated", "InitializationMode", ...). */
const char *fpm_mode_name(int mode);
/* 1 if `mode` is in `mask`; else 0 with "<fn> is not allowed in state <mode>" logged. */
int fpm_allowed(const fpm_logger *lg, const char *fn, int mode, int mask);
/* Check one get or set call before anything is read or written: a NULL array with n > 0,
 * every value reference against the table, its type, and for a set (set = 1) its causality
 * (no output; a parameter only in FPM_MASK_SET_PARAMETER). type_names: the version's names of
 * FPM_REAL .. FPM_STRING. 1, or 0 with the reason logged. */
int fpm_check_access(const fpm_logger *lg, const char *fn, int mode, const unsigned vr[],
                     size_t n, const void *values, int type, int set,
                     const char *const type_names[4]);
/* The start values of the table's parameters and inputs. */
void fpm_start_values(fpm_values *v);
/* The index of vr in the table, or -1 (no such variable). */
int fpm_lookup(unsigned vr);
/* A 64-bit FNV-1a hash. */
unsigned long long fpm_hash(const void *data, size_t n, unsigned long long h);

/* ---- Serialised FMU states: the writer and reader a model saves and loads with ------------ */
typedef struct fpm_writer {
    unsigned char *p;          /* NULL: only count */
    size_t n, cap;
} fpm_writer;

typedef struct fpm_reader {
    const unsigned char *p;
    size_t n, pos;
    int interface;             /* the instance's (FPM_COSIMULATION, FPM_MODEL_EXCHANGE): a model
                                  checks what only its legal calls can reach */
    char why[FPM_MSG_MAX];     /* the first thing that was wrong */
} fpm_reader;

void fpm_put_f64(fpm_writer *w, double x);
void fpm_put_i32(fpm_writer *w, int x);
void fpm_put_str(fpm_writer *w, const char *s);
/* Each reads one item; 0 (and r->why set) when the data end or the item is malformed. */
int fpm_get_f64(fpm_reader *r, const char *what, double *x);
int fpm_get_i32(fpm_reader *r, const char *what, int *x);
int fpm_get_str(fpm_reader *r, const char *what, char *dst, size_t cap);
/* Read a double that must be finite (0 and why otherwise). */
int fpm_get_finite(fpm_reader *r, const char *what, double *x);
/* Read an integer in lo..hi (0 and why otherwise). */
int fpm_get_int_in(fpm_reader *r, const char *what, int lo, int hi, int *x);
/* A logger whose first error message becomes r's reason (the checks of initialisation, run on a
 * restored state, say why through it). */
fpm_logger fpm_reader_logger(fpm_reader *r);
/* Mark the state invalid with a reason (printf format); returns 0. */
int fpm_reject(fpm_reader *r, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* ---- What each model implements ---------------------------------------------------------- */
typedef struct fpm_model fpm_model;
size_t fpm_model_size(void);
/* Start values and a clean state (calloc'ed memory, or a reset). */
void fpm_model_reset(fpm_model *m, double start_time);
fpm_values *fpm_model_values(fpm_model *m);
/* exitInitializationMode: check every parameter (FPM_ERROR with a message naming the bad one),
 * prepare, and check that the initial outputs are finite. */
int fpm_model_init(fpm_model *m, const fpm_logger *lg);
/* One communication step from t over h (h > 0 and finite, t + h > t, checked by the caller).
 * The step is taken whole (the time becomes t + h and the outputs are finite) or refused with a
 * message. */
int fpm_model_step(fpm_model *m, const fpm_logger *lg, double t, double h);
/* The time the model has reached. */
double fpm_model_time(const fpm_model *m);
/* The value of output vr (before initialisation: from the parameters as they are). A value that
 * is not finite is refused (FPM_ERROR with a message). */
int fpm_model_get_output(fpm_model *m, const fpm_logger *lg, unsigned vr, double *value);
/* The order-th time derivative (1 or 2) of input vr over the next steps (FMI 2.0's
 * fmi2SetRealInputDerivatives); FPM_ERROR if the input cannot take it. */
int fpm_model_set_input_derivative(fpm_model *m, const fpm_logger *lg, unsigned vr, int order,
                                   double value);
/* 1 once fpm_model_init succeeded (until a reset). */
int fpm_model_initialized(const fpm_model *m);
/* Write the model's independent state (its time, physical state, held inputs and their
 * derivatives, and what legal calls leave behind: a refusal's reason); the table's values are
 * written by the core. */
void fpm_model_save(const fpm_model *m, fpm_writer *w);
/* Read what fpm_model_save wrote into m, which is fresh (fpm_model_reset) and holds the values
 * the core read. Validate every item (finiteness, the parameters' ranges with the checks of
 * initialisation, sizes against the model) and rebuild every derived field with the code
 * initialisation uses. initialized: 1 the mode needs an initialised model, 0 it needs one that
 * is not, -1 either. live: NULL, or the instance's live model (read only): a model may take
 * from it the derived fields it would rebuild bit for bit the same (when everything they derive
 * from is bitwise equal in both and live is initialised), instead of rebuilding them; every
 * item read from r is validated all the same. 1, or 0 with r->why set. */
int fpm_model_load(fpm_model *m, fpm_reader *r, int initialized, const fpm_model *live);
/* After a restore loaded m (fpm_model_load succeeded) and before m replaces the live model
 * `from`: carry over from `from` the derived data that m would compute bit for bit the same
 * (a cache, when what it derives from is bitwise equal in both), so that a master that restores
 * a state every step does not recompute them. Doing nothing is correct. */
void fpm_model_keep(fpm_model *m, const fpm_model *from);

/* ---- Jacobians and output derivatives: what each model implements (issue 24) ---------------
 * Indices, not value references: the core maps value references to them.
 *   state i   0 .. fpm_model_nx() - 1, in the order the modelDescription declares the states;
 *   input j   0 .. NU - 1, the native table's inputs in table order (the plant: F_c; the
 *             controller: phi_o, omega_o, x_o);
 *   output k  0 .. NY - 1, the table's outputs in table order.
 * NU and NY follow from the generated table (fpm_vars). */

/* The number of continuous states the FMU declares: a constant of the build (the plant declares
 * the states of its largest Model-Exchange n_modes; the states of modes beyond the instance's
 * n_modes stay 0 and have derivative 0). */
size_t fpm_model_nx(void);

/* The dense linearisation at the model's current time, state and inputs (Model Exchange: the
 * state and inputs last set; co-simulation: the state reached by the last step, with the inputs
 * as their polynomial gives them at that time): A = d(der x)/dx (nx x nx), B = d(der x)/du
 * (nx x NU), C = dy/dx (NY x nx), D = dy/du (NY x NU), row-major, exact (analytic). Any pointer
 * may be NULL (that block is not wanted). FPM_OK, or FPM_ERROR with a message (not initialised,
 * a non-finite entry). */
int fpm_model_jacobian(fpm_model *m, const fpm_logger *lg, double *A, double *B, double *C,
                       double *D);

/* values[i] = the order[i]-th time derivative (1 .. fpm_model_max_output_derivative_order())
 * of output vr[i] at the model's current time, i = 0 .. n - 1: exact, for the inputs as their
 * polynomial (value and input derivatives) gives them at that time. One call for the whole
 * request (fmi2GetRealOutputDerivatives'), so that a model evaluates its derivatives once for
 * all entries; entries taken in order, the first bad one refused as it would be alone. FPM_OK
 * with every value finite, or FPM_ERROR with a message (the core checks the values finite only
 * after the call, and names the first that is not). */
int fpm_model_output_derivatives(fpm_model *m, const fpm_logger *lg, size_t n,
                                 const unsigned vr[], const int order[], double values[]);
/* The highest order fpm_model_output_derivatives gives exactly (the modelDescription's
 * maxOutputDerivativeOrder; 0: none). */
int fpm_model_max_output_derivative_order(void);
/* What the FMU offers besides co-simulation, as its modelDescription declares it (generated
 * into fpm_vars.h from fmu_common.variables.Offers): 1 if it offers Model Exchange, 1 if it
 * provides directional derivatives. The core refuses what is not offered before the model's
 * code is reached; what is offered, the model gives at every parameter value it accepts. */
int fpm_model_offers_me(void);
int fpm_model_offers_jacobian(void);

/* ---- Model Exchange: what each model implements (issue 24) ---------------------------------
 * The states, derivatives, nominals and event indicators of Model Exchange, by index (the
 * table's fpm_var.state / .der / .indicator give the value references). The model keeps its
 * Model-Exchange state in the fields its co-simulation state lives in, so that FMU states save
 * and restore it with fpm_model_save and fpm_model_load. */
/* The number of event indicators (a constant of the build). */
size_t fpm_model_nz(void);
/* At exitInitializationMode of a Model-Exchange instance, after fpm_model_init: what only Model
 * Exchange refuses (FPM_ERROR with a message). */
int fpm_model_me_init(fpm_model *m, const fpm_logger *lg);
/* The time (fmi2SetTime; finite, the caller checks): FPM_ERROR with a message if the model
 * refuses it (before its start time). */
int fpm_model_set_time(fpm_model *m, const fpm_logger *lg, double t);
/* The states (fpm_model_nx() doubles) get and set; set refuses non-finite values (FPM_ERROR
 * with a message, nothing changed). */
void fpm_model_get_states(const fpm_model *m, double *x);
int fpm_model_set_states(fpm_model *m, const fpm_logger *lg, const double *x);
/* The derivatives at the current time, states and inputs; FPM_ERROR with a message if an input
 * or a result is not finite. */
int fpm_model_derivatives(fpm_model *m, const fpm_logger *lg, double *dx);
/* Nominal values of the states (> 0, finite). */
void fpm_model_nominals(const fpm_model *m, double *nominal);
/* The event indicators (fpm_model_nz() doubles, finite): FPM_OK or FPM_ERROR with a message. */
int fpm_model_event_indicators(fpm_model *m, const fpm_logger *lg, double *z);
/* In event mode (fmi2NewDiscreteStates, fmi3UpdateDiscreteStates): *terminate = 1 (and a
 * message naming the bound) when the model cannot go on. */
int fpm_model_event_update(fpm_model *m, const fpm_logger *lg, int *terminate);
/* The value of a Model-Exchange local vr (a state, a derivative, an event indicator). */
int fpm_model_get_local(fpm_model *m, const fpm_logger *lg, unsigned vr, double *value);

/* ---- Clocks (FMI 3.0 co-simulation with event mode; issue 38) ------------------------------
 * A model with clocks (the sampled controller: FPM_N_CLOCKS > 0 in its fpm_vars.h) implements
 * these; the generated fpm_vars.h of every other model defines them as a model without clocks
 * (fpm_model_clock_of is -1 for every value reference, so fmi3.c refuses every clock call).
 * clock: 0 .. FPM_N_CLOCKS - 1. The clocks' value references are not in the table (fpm_vars):
 * they are declared by the FMI 3.0 description only, after every value reference of the table.
 * An instance uses its clocks when its importer uses event mode (fmi3InstantiateCoSimulation's
 * eventModeUsed); fmi3.c tells the model before every call that depends on it
 * (fpm_model_use_clocks), so that a reset or a restored FMU state (neither of which holds it)
 * cannot lose it. A restored state has no clock active. */
/* The number of clocks (FPM_N_CLOCKS), and the clock of value reference vr, or -1. */
int fpm_model_n_clocks(void);
int fpm_model_clock_of(unsigned vr);
/* on = 1: the instance uses event mode: the model's clocked partitions run at the activations
 * of their clocks (fmi3SetClock, fmi3UpdateDiscreteStates), not inside doStep. */
void fpm_model_use_clocks(fpm_model *m, int on);
/* A periodic clock's interval and its shift from the start time (from the parameters as they
 * are set now): FPM_OK, or FPM_ERROR with a message (a parameter that gives none). */
int fpm_model_clock_timing(fpm_model *m, const fpm_logger *lg, const char *fn, int clock,
                           double *interval, double *shift);
/* fmi3SetClock of one clock in event mode: FPM_OK, or FPM_ERROR with a message (not its
 * instant, a deactivation the clock refuses). apply = 0: the checks only (a call setting
 * several clocks checks them all before it changes any). */
int fpm_model_set_clock(fpm_model *m, const fpm_logger *lg, const char *fn, int clock,
                        int active, int apply);
/* 1 if the clock is active. */
int fpm_model_get_clock(const fpm_model *m, int clock);
/* The end of a super-dense instant (fmi3UpdateDiscreteStates; fmi3EnterStepMode with a clock
 * still active): the active clocks' partitions run, then every clock is deactivated. FPM_OK, or
 * FPM_ERROR with a message and nothing changed. */
int fpm_model_clock_update(fpm_model *m, const fpm_logger *lg);
/* Before a set of vr[0 .. n-1] in mode `mode`: FPM_OK, or FPM_ERROR with a message when one of
 * them is a clocked variable whose clock is not active (a clocked input is set at its clock's
 * activation, or before initialisation ends). */
int fpm_model_clocked_set(fpm_model *m, const fpm_logger *lg, const char *fn, int mode,
                          const unsigned vr[], size_t n);

/* ---- The core (fpm_core.c) ---------------------------------------------------------------- */
typedef struct fpm_instance fpm_instance;
/* Sends one message to the host (the adapter's logger). */
typedef void (*fpm_host_emit)(fpm_instance *c, int status, const char *category,
                              const char *message);

struct fpm_instance {
    fpm_logger lg;             /* messages of this instance (emit -> host_emit) */
    fpm_host_emit host_emit;
    void *host;                /* the adapter's copy of the host's callbacks (host_size bytes) */
    char name[128];
    int log_mask;              /* bit s: category fpm_log_categories[s] is enabled (bit 0: logAll,
                                  the debug messages; fpm_log_wanted) */
    long time_vr;              /* the value reference of `time` (FMI 3.0: fpm_time_vr, which
                                  GetFloat64 reads as the instance's time), -1: none (FMI 2.0) */
    char event_said[FPM_MSG_MAX]; /* the last warning of an event update (each event's message
                                     once: fpm_me_update_discrete) */
    int event_repeat;          /* the current event update repeated event_said */
    int interface;             /* FPM_COSIMULATION or FPM_MODEL_EXCHANGE */
    int modes;                 /* the modes this instance can reach */
    int mode;
    int discarded;             /* the model refused the last doStep (the master should stop) */
    fpm_model *m;              /* the model */
    fpm_model *spare;          /* where a state is restored before it replaces the model */
    unsigned long long identity; /* the model's identity in a state's header (name, token and
                                    format hashed: a constant, computed at instantiation) */
    size_t state_cap;          /* bytes of a serialised state, at most */
    unsigned char *scratch;    /* state_cap bytes: a state is serialised here, then copied into
                                  a state of its own size */
    size_t jac_n;              /* doubles in jac */
    double *jac;               /* the model's linearisation [[A, B], [C, D]] of directional
                                  derivatives, (nx + NY) x (nx + NU) */
};

/* A new instance (NULL, logged, if the token is not this FMU's or memory is short). host: the
 * adapter's callbacks, copied (host_size bytes). modes: the modes the interface has. */
fpm_instance *fpm_instantiate(const char *fn, const char *name, const char *token,
                              int interface, int modes, const void *host, size_t host_size,
                              fpm_host_emit emit, int logging_on);
void fpm_free_instance(fpm_instance *c);
/* Each returns an FPM_* status and logs the reason of any other than FPM_OK; `fn` is the
 * adapter's function name and `mask` the modes it is allowed in. */
int fpm_set_debug_logging(fpm_instance *c, const char *fn, int mask, int on, size_t n,
                          const char *const categories[]);
/* 1 if a message of `status` goes to the host (its category, or logAll, is enabled). */
int fpm_log_wanted(const fpm_instance *c, int status);
int fpm_enter_init(fpm_instance *c, const char *fn, int mask, double start, int stop_defined,
                   double stop, int enter);
int fpm_exit_init(fpm_instance *c, const char *fn, int mask, int next_mode);
int fpm_set_mode(fpm_instance *c, const char *fn, int mask, int mode);
int fpm_reset(fpm_instance *c, const char *fn, int mask);

/* How values are laid out in the caller's array. */
#define FPM_C_DOUBLE 0
#define FPM_C_INT 1          /* int (fmi2Integer, fmi2Boolean, fmi3Int32) */
#define FPM_C_BOOL 2         /* a one-byte bool (fmi3Boolean) */
#define FPM_C_STRING 3       /* const char * */
int fpm_get(fpm_instance *c, const char *fn, int mask, const unsigned vr[], size_t n,
            void *values, int type, int layout, const char *const type_names[4]);
int fpm_set(fpm_instance *c, const char *fn, int mask, const unsigned vr[], size_t n,
            const void *values, int type, int layout, const char *const type_names[4]);
int fpm_set_input_derivatives(fpm_instance *c, const char *fn, int mask, const unsigned vr[],
                              size_t n, const int order[], const double values[]);
int fpm_do_step(fpm_instance *c, const char *fn, int mask, double t, double h);
double fpm_time(const fpm_instance *c);

/* FMU states: a state is the serialised bytes of the instance (magic, format, size, the
 * model's identity, the payload, a checksum), in memory. */
int fpm_get_state(fpm_instance *c, const char *fn, int mask, void **state);
int fpm_set_state(fpm_instance *c, const char *fn, int mask, const void *state);
int fpm_free_state(fpm_instance *c, const char *fn, int mask, void **state);
int fpm_state_size(fpm_instance *c, const char *fn, int mask, const void *state, size_t *size);
int fpm_serialize_state(fpm_instance *c, const char *fn, int mask, const void *state,
                        unsigned char *data, size_t size);
int fpm_deserialize_state(fpm_instance *c, const char *fn, int mask, const unsigned char *data,
                          size_t size, void **state);
/* Model Exchange (each checks the interface, the mode and its arguments; a refusal is logged). */
int fpm_me_set_time(fpm_instance *c, const char *fn, int mask, double t);
int fpm_me_set_states(fpm_instance *c, const char *fn, int mask, const double x[], size_t nx);
int fpm_me_get_states(fpm_instance *c, const char *fn, int mask, double x[], size_t nx);
int fpm_me_get_derivatives(fpm_instance *c, const char *fn, int mask, double dx[], size_t nx);
int fpm_me_get_nominals(fpm_instance *c, const char *fn, int mask, double x[], size_t nx);
int fpm_me_get_event_indicators(fpm_instance *c, const char *fn, int mask, double z[],
                                size_t nz);
/* event mode: *terminate = 1 when the model cannot go on */
int fpm_me_update_discrete(fpm_instance *c, const char *fn, int mask, int *terminate);
/* completedIntegratorStep: *terminate as above (the bounds crossed between events) */
int fpm_me_completed_step(fpm_instance *c, const char *fn, int mask, int *terminate);
/* A mode change that only an instance of `interface` makes. */
int fpm_set_mode_of(fpm_instance *c, const char *fn, int interface, int mask, int mode);

/* Directional derivatives (both interfaces): sensitivity = J seed, J the block of the model's
 * linearisation (fpm_model_jacobian) of the unknowns (derivatives and outputs) with respect to
 * the knowns (states and inputs). */
int fpm_directional_derivative(fpm_instance *c, const char *fn, int mask,
                               const unsigned unknowns[], size_t n_unknowns,
                               const unsigned knowns[], size_t n_knowns, const double seed[],
                               double sensitivity[]);
/* Output derivatives (co-simulation): values[i] = the order[i]-th time derivative of output
 * vr[i]. */
int fpm_output_derivatives(fpm_instance *c, const char *fn, int mask, const unsigned vr[],
                           size_t n, const int order[], double values[]);

/* Log "fn: what" with status (for what an adapter refuses itself); returns status. */
int fpm_refuse(fpm_instance *c, int status, const char *fn, const char *what);

#ifdef __cplusplus
}
#endif

#endif /* FPM_H */
