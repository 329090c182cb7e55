/*
 * fpm.h - what a model gives the generic FMI layers (fmi2.c, fmi3.c), and what they give it.
 *
 * The shape of the Modelica Reference-FMUs, our own code: the FMI interface is written once per
 * FMI version; a model (plant_model.c, controller_model.c) contributes
 *   - its table of variables, generated at build time from the Python table of the model
 *     (plant_fmu/interface.py, controller_fmu/interface.py) into fpm_vars.h;
 *   - its data, one flat struct (fpm_model) holding every value and state, so that an FMU
 *     state is a copy of it (relinked by fpm_model_relink when its arrays are pointed to);
 *   - its parameter checks (fpm_model_init), its step (fpm_model_step) and its outputs.
 *
 * Contract: C99 plus libm; no global mutable state (every instance is its own memory);
 * no allocation after instantiation except for FMU states the host asks for; every non-OK status
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

#define FPM_MAX_VARS 48       /* value references 0 .. FPM_MAX_VARS - 1 */
#define FPM_STR_MAX 32        /* longest string value, with its terminating 0 */
#define FPM_MSG_MAX 512       /* longest log message */

/* Relative tolerance on the communication point of doStep against the model's own time (the
 * pythonfmu slaves' TIME_RTOL). */
#define FPM_TIME_RTOL 1e-9

/* One variable of the table (generated into fpm_vars.h). */
typedef struct fpm_var {
    const char *name;
    int type;                 /* FPM_REAL .. FPM_STRING */
    int causality;            /* FPM_PARAMETER, FPM_INPUT, FPM_OUTPUT */
    double start_real;        /* start of a Real, Integer (exact) or Boolean (0/1) */
    const char *start_string; /* start of a String */
} fpm_var;

/* The values of the parameters and inputs, indexed by value reference. */
typedef struct fpm_values {
    double real[FPM_MAX_VARS];           /* Real, Integer and Boolean values */
    char string[FPM_MAX_VARS][FPM_STR_MAX];
} fpm_values;

/* The logger the FMI layer hands to the model for one call. */
typedef struct fpm_logger {
    void (*emit)(void *env, int status, const char *category, const char *message);
    void *env;
} fpm_logger;

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

/* ---- What each model implements ---------------------------------------------------------- */
typedef struct fpm_model fpm_model;
size_t fpm_model_size(void);
/* Start values and a clean state (calloc'ed memory, or a reset). */
void fpm_model_reset(fpm_model *m, double start_time);
fpm_values *fpm_model_values(fpm_model *m);
/* exitInitializationMode: check every parameter (FPM_ERROR with a message naming the bad one)
 * and prepare. */
int fpm_model_init(fpm_model *m, const fpm_logger *lg);
/* One communication step from t over h (h > 0 and finite, checked by the caller). */
int fpm_model_step(fpm_model *m, const fpm_logger *lg, double t, double h);
/* The time the model has reached. */
double fpm_model_time(const fpm_model *m);
/* The value of output vr (before initialisation: from the parameters as they are). */
int fpm_model_get_output(fpm_model *m, const fpm_logger *lg, unsigned vr, double *value);
/* The order-th time derivative (1 or 2) of input vr over the next steps (FMI 2.0's
 * fmi2SetRealInputDerivatives); FPM_ERROR if the input cannot take it. */
int fpm_model_set_input_derivative(fpm_model *m, const fpm_logger *lg, unsigned vr, int order,
                                   double value);
/* After the struct was copied in (an FMU state restored): point its arrays at itself, and
 * check it (FPM_ERROR with a message if it is not a state of this model). */
int fpm_model_relink(fpm_model *m, const fpm_logger *lg);

/* ---- Shared by the FMI layers (fpm_util.c) ----------------------------------------------- */
/* The start values of the table's parameters and inputs. */
void fpm_start_values(fpm_values *v);
/* The index of vr in the table, or -1 (no such variable). */
int fpm_lookup(unsigned vr);
/* A 64-bit FNV-1a hash. */
unsigned long long fpm_hash(const void *data, size_t n, unsigned long long h);
/* The bytes of a serialised FMU state of `size` bytes of model (with `mode`): header, payload,
 * checksum. */
size_t fpm_serialized_size(size_t size);
void fpm_serialize(const void *mode_and_model, size_t size, unsigned char *out);
/* Check a serialised state and copy its payload into `mode_and_model` (size bytes); FPM_OK or
 * FPM_ERROR with the reason in why (FPM_MSG_MAX bytes). */
int fpm_deserialize(const unsigned char *in, size_t n, void *mode_and_model, size_t size,
                    char *why);

#ifdef __cplusplus
}
#endif

#endif /* FPM_H */
