/* fpm_core.c - the instance core of the native FMUs, version-neutral (see fpm.h): life cycle,
 * variable access through the generated table, doStep's checks, and FMU states.
 *
 * FMU states. A state, in memory or serialised, is one byte string: "FPMS", the format
 * version, the payload's size, the model's identity (name, token and format hashed), the payload
 * and an FNV-1a checksum of everything before it. The payload holds only independent quantities:
 * the mode and the refusal flag, the values of the table's parameters and inputs, and what the
 * model saves (fpm_model_save). The checksum catches accidents, not intent: anyone can recompute
 * it, so a restore trusts nothing. It reads the payload into the instance's spare model, checks
 * every item (fpm_model_load: ranges, finiteness, sizes) and rebuilds every derived quantity with
 * the code initialisation uses; only when all of it succeeded does the spare model replace the
 * live one. A crafted state can at worst hold a state that legal calls could reach, and a failed
 * restore leaves the instance as it was.
 *
 * An FMU state in memory (fmi2GetFMUstate, fmi3GetFMUState) holds the same bytes, but its
 * FNV-1a trailer is written only when it is serialised (and checked when it is deserialised):
 * in memory a word-wise checksum kept beside the bytes (memory_sum) guards them, checked on
 * every restore and serialisation. It catches the same accidents at a fraction of the cost (the
 * byte-wise FNV-1a is one dependent multiplication a byte; an implicit master's step restores
 * both FMUs' states several times). */
#include "fpm.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define FPM_LOG_STATUS 30   /* the mask of the status categories (Warning .. Fatal) */
#define MAGIC "FPMS"
#define FORMAT 3u     /* 3: the models save whether a step was taken (issue 24) */
#define HEADER 24u
#define STATE_MAGIC 0x46504d5354415445ULL    /* "FPMSTATE": a state this core allocated */

typedef struct state {
    unsigned long long magic;
    size_t n, cap;                 /* bytes used, bytes allocated in data */
    unsigned long long sum;        /* memory_sum of the first n - 8 bytes of data */
    unsigned char data[1];         /* n bytes (allocated with cap); the last 8: see below */
} state;

static unsigned long long identity(void);

static void core_emit(void *env, int status, const char *category, const char *message)
{
    fpm_instance *c = (fpm_instance *)env;
    c->host_emit(c, status, category, message);
}

int fpm_refuse(fpm_instance *c, int status, const char *fn, const char *what)
{
    if (c != NULL) fpm_log(&c->lg, status, "%s: %s", fn, what);
    return status;
}

/* The mode check of every call (the message from the guard only when it fails: this is on the
 * path of every call a master makes). */
#define GUARD(c, fn, mask)                                                                    \
    do {                                                                                      \
        if ((c) == NULL) return FPM_ERROR;                                                    \
        if (!((c)->mode & (mask)) && !fpm_allowed(&(c)->lg, fn, (c)->mode, mask))             \
            return FPM_ERROR;                                                                 \
    } while (0)

/* fpm_check_access's verdict without its messages, inline for the calls of every step; the guard
 * is asked (and logs) only when this says no. */
static int access_ok(int mode, const unsigned vr[], size_t n, const void *values, int type,
                     int set)
{
    size_t i;
    if (n > 0 && (vr == NULL || values == NULL)) return 0;
    for (i = 0; i < n; i++) {
        const fpm_var *v;
        if (vr[i] >= FPM_MAX_VARS) return 0;
        v = &fpm_vars[vr[i]];
        if (v->name == NULL || v->type != type) return 0;
        if (set && (v->causality == FPM_OUTPUT || v->causality == FPM_LOCAL ||
                    (v->causality == FPM_PARAMETER && !(mode & FPM_MASK_SET_PARAMETER))))
            return 0;
    }
    return 1;
}

#define ACCESS(c, fn, vr, n, values, type, set, names)                                        \
    (access_ok((c)->mode, vr, n, values, type, set) ||                                        \
     fpm_check_access(&(c)->lg, fn, (c)->mode, vr, n, values, type, set, names))

/* The number of the table's variables of one causality (inputs, outputs). */
static int count_vars(int causality)
{
    int i, n = 0;
    for (i = 0; i < FPM_MAX_VARS; i++)
        if (fpm_vars[i].name != NULL && fpm_vars[i].causality == causality) n++;
    return n;
}

/* The number of the table's continuous states (fpm_var.state). */
static size_t count_states(void)
{
    size_t i, n = 0;
    for (i = 0; i < FPM_MAX_VARS; i++)
        if (fpm_vars[i].name != NULL && fpm_vars[i].state) n++;
    return n;
}

/* The index of vr among the table's variables of its causality (inputs, outputs). */
static int index_among(unsigned vr, int causality)
{
    unsigned i;
    int n = 0;
    for (i = 0; i < vr; i++)
        if (fpm_vars[i].name != NULL && fpm_vars[i].causality == causality) n++;
    return n;
}

/* ------------------------------------------------------------------ life cycle */
fpm_instance *fpm_instantiate(const char *fn, const char *name, const char *token,
                              int interface, int modes, const void *host, size_t host_size,
                              fpm_host_emit emit, int logging_on)
{
    fpm_instance tmp, *c;
    unsigned char *block;
    size_t head = (sizeof(fpm_instance) + 15u) / 16u * 16u;
    size_t hsize = (host_size + 15u) / 16u * 16u;
    memset(&tmp, 0, sizeof tmp);
    tmp.host = (void *)host;
    tmp.host_emit = emit;
    tmp.lg.emit = core_emit;
    tmp.lg.env = &tmp;
    tmp.log_mask = FPM_LOG_STATUS | (logging_on ? 1 : 0);
    tmp.time_vr = -1;
    tmp.identity = identity();
    strncpy(tmp.name, name ? name : "?", sizeof tmp.name - 1);
    if (interface != FPM_COSIMULATION && interface != FPM_MODEL_EXCHANGE) {
        fpm_log(&tmp.lg, FPM_ERROR, "%s: unknown FMU type %d (co-simulation or model exchange)",
                fn, interface);
        return NULL;
    }
    if (interface == FPM_MODEL_EXCHANGE && !fpm_model_offers_me()) {
        fpm_log(&tmp.lg, FPM_ERROR, "%s: %s offers co-simulation only (its modelDescription "
                "declares no ModelExchange)", fn, fpm_model_name);
        return NULL;
    }
    if (fpm_model_offers_me() && fpm_model_nx() != count_states()) {  /* a broken build: the
                                                                         model and table disagree */
        fpm_log(&tmp.lg, FPM_ERROR, "%s: %s declares %lu continuous states but its model has "
                "%lu (a broken build)", fn, fpm_model_name, (unsigned long)count_states(),
                (unsigned long)fpm_model_nx());
        return NULL;
    }
    if (token == NULL || strcmp(token, fpm_token) != 0) {
        fpm_log(&tmp.lg, FPM_ERROR, "%s: the GUID / instantiation token %s is not this FMU's "
                "(%s): the modelDescription.xml and the binary come from different builds", fn,
                token ? token : "(null)", fpm_token);
        return NULL;
    }
    /* a serialised state is at most: header, mode and flag, every value as its widest item,
     * the model's items (each no wider than its part of the struct; a string 4 bytes more),
     * checksum */
    tmp.state_cap = HEADER + 8u + FPM_MAX_VARS * (8u + 4u + FPM_STR_MAX) + fpm_model_size() + 64u
                    + 8u;
    /* the dense linearisation of directional derivatives: (nx + NY) x (nx + NU) doubles */
    tmp.jac_n = (fpm_model_nx() + (size_t)count_vars(FPM_OUTPUT)) *
                (fpm_model_nx() + (size_t)count_vars(FPM_INPUT));
    /* the instance, the host's callbacks, two models, the scratch buffer and the Jacobian's
     * buffer in one block */
    block = (unsigned char *)calloc(1, head + hsize + 2 * ((fpm_model_size() + 15u) / 16u * 16u)
                                           + (tmp.state_cap + 15u) / 16u * 16u
                                           + tmp.jac_n * sizeof(double));
    if (block == NULL) {
        fpm_log(&tmp.lg, FPM_ERROR, "%s: out of memory", fn);
        return NULL;
    }
    c = (fpm_instance *)block;
    *c = tmp;
    c->lg.env = c;
    c->host = block + head;
    if (host_size) memcpy(c->host, host, host_size);
    c->m = (fpm_model *)(block + head + hsize);
    c->spare = (fpm_model *)(block + head + hsize + (fpm_model_size() + 15u) / 16u * 16u);
    c->scratch = block + head + hsize + 2 * ((fpm_model_size() + 15u) / 16u * 16u);
    c->jac = (double *)(c->scratch + (c->state_cap + 15u) / 16u * 16u);
    c->interface = interface;
    c->modes = modes;
    c->mode = FPM_INSTANTIATED;
    fpm_model_reset(c->m, 0.0);
    return c;
}

void fpm_free_instance(fpm_instance *c)
{
    free(c);
}

/* Log categories. A message's category is its status's (fpm_log_categories); the host enables
 * and disables categories, and a message goes out when its category or logAll is enabled:
 *   instantiation     the status categories (Warning, Discard, Error, Fatal) enabled: a non-OK
 *                     status comes with its reason whatever loggingOn says; logAll (the debug
 *                     messages) as loggingOn says;
 *   on, none named    every category enabled;
 *   off, none named   logAll disabled (no debug messages); the status categories stay, as at
 *                     instantiation: the reason of a refusal is silenced only on request, by name;
 *   on, named         only the named categories enabled (FMI 2.0 section 2.1.5: "only debug
 *                     messages according to the categories argument shall be output");
 *   off, named        the named categories disabled, the others unchanged.
 * An unknown category (or a NULL name) is refused with Error, and nothing changes. */
int fpm_log_wanted(const fpm_instance *c, int status)
{
    if (status < FPM_OK || status > FPM_FATAL) return 1;
    return (c->log_mask & 1) || (c->log_mask & (1 << status));
}

int fpm_set_debug_logging(fpm_instance *c, const char *fn, int mask, int on, size_t n,
                          const char *const categories[])
{
    size_t i;
    int named = 0;
    GUARD(c, fn, mask);
    if (n > 0 && categories == NULL)
        return fpm_refuse(c, FPM_ERROR, fn, "categories is NULL but nCategories > 0");
    for (i = 0; i < n; i++) {
        int k = fpm_log_category(categories[i]);
        if (k < 0) {
            char allowed[128] = "";
            int j;
            for (j = 0; j < FPM_N_CATEGORIES; j++) {
                if (j) strcat(allowed, ", ");
                strcat(allowed, fpm_log_categories[j]);
            }
            fpm_log(&c->lg, FPM_ERROR, "%s: unknown log category %s%s%s (categories[%lu]); "
                    "allowed: %s; the logging is unchanged", fn, categories[i] ? "'" : "",
                    categories[i] ? categories[i] : "NULL", categories[i] ? "'" : "",
                    (unsigned long)i, allowed);
            return FPM_ERROR;
        }
        named |= 1 << k;
    }
    if (n == 0) c->log_mask = on ? FPM_LOG_STATUS | 1 : c->log_mask & ~1;
    else if (on) c->log_mask = named;
    else c->log_mask &= ~named;
    return FPM_OK;
}

int fpm_enter_init(fpm_instance *c, const char *fn, int mask, double start, int stop_defined,
                   double stop, int enter)
{
    fpm_values v;
    GUARD(c, fn, mask);
    if (!isfinite(start) || (stop_defined && !(stop >= start))) {
        fpm_log(&c->lg, FPM_ERROR, "%s: startTime = %.17g, stopTime = %.17g: the start must be "
                "finite and not after the stop", fn, start, stop);
        return FPM_ERROR;
    }
    v = *fpm_model_values(c->m);          /* keep the values set so far, restart the time */
    fpm_model_reset(c->m, start);
    *fpm_model_values(c->m) = v;
    c->event_said[0] = '\0';
    if (enter) c->mode = FPM_INIT;
    return FPM_OK;
}

int fpm_exit_init(fpm_instance *c, const char *fn, int mask, int next_mode)
{
    int rc;
    GUARD(c, fn, mask);
    rc = fpm_model_init(c->m, &c->lg);
    if (rc <= FPM_WARNING && c->interface == FPM_MODEL_EXCHANGE) {
        int rc2 = fpm_model_me_init(c->m, &c->lg);
        if (rc2 > rc) rc = rc2;
    }
    if (rc > FPM_WARNING) {
        c->mode = FPM_ERROR_MODE;
        return FPM_ERROR;
    }
    c->mode = next_mode;
    return rc;
}

int fpm_set_mode(fpm_instance *c, const char *fn, int mask, int mode)
{
    GUARD(c, fn, mask);
    c->mode = mode;
    return FPM_OK;
}

static const char *interface_name(int interface)
{
    return interface == FPM_MODEL_EXCHANGE ? "Model Exchange" : "co-simulation";
}

/* 1 if c is an instance of `interface`, else 0 with the refusal logged. */
static int of_interface(fpm_instance *c, const char *fn, int interface)
{
    if (c->interface == interface) return 1;
    fpm_log(&c->lg, FPM_ERROR, "%s: a call of %s, but this instance of %s was instantiated for "
            "%s", fn, interface_name(interface), fpm_model_name, interface_name(c->interface));
    return 0;
}

#define INTERFACE(c, fn, interface)                                                           \
    do {                                                                                      \
        if ((c) == NULL) return FPM_ERROR;                                                    \
        if (!of_interface(c, fn, interface)) return FPM_ERROR;                                \
    } while (0)

int fpm_set_mode_of(fpm_instance *c, const char *fn, int interface, int mask, int mode)
{
    INTERFACE(c, fn, interface);
    return fpm_set_mode(c, fn, mask, mode);
}

int fpm_reset(fpm_instance *c, const char *fn, int mask)
{
    GUARD(c, fn, mask);
    fpm_model_reset(c->m, 0.0);
    c->mode = FPM_INSTANTIATED;
    c->discarded = 0;
    c->event_said[0] = '\0';                  /* a new run says its events anew */
    return FPM_OK;
}

double fpm_time(const fpm_instance *c) { return fpm_model_time(c->m); }

/* ------------------------------------------------------------------ variables */
/* FMI 3.0's independent variable `time` (c->time_vr; FMI 2.0 declares none). It is no entry of
 * the table (FMI 2.0 leaves it out with the same value references): a get or set that names it
 * takes one of these ways, every other call the table's. Its value is the instance's time
 * (fpm_time): startTime after fmi3EnterInitializationMode, the time a doStep reached
 * (co-simulation), the time last set by fmi3SetTime (Model Exchange). */
static int names_time(const fpm_instance *c, const unsigned vr[], size_t n)
{
    size_t i;
    if (c->time_vr < 0 || vr == NULL) return 0;
    for (i = 0; i < n; i++)
        if ((long)vr[i] == c->time_vr) return 1;
    return 0;
}

static int get_with_time(fpm_instance *c, const char *fn, int mask, const unsigned vr[],
                         size_t n, void *values, int type, int layout,
                         const char *const type_names[4])
{
    size_t i;
    int worst = FPM_OK;
    if (type != FPM_REAL) {
        fpm_log(&c->lg, FPM_ERROR, "%s: variable time (value reference %ld) is of type %s, not "
                "%s", fn, c->time_vr, type_names[FPM_REAL], type_names[type]);
        return FPM_ERROR;
    }
    if (values == NULL) {
        fpm_log(&c->lg, FPM_ERROR, "%s: the value array is NULL but %lu values are asked for",
                fn, (unsigned long)n);
        return FPM_ERROR;
    }
    for (i = 0; i < n; i++) {
        int rc = FPM_OK;
        if ((long)vr[i] == c->time_vr)
            ((double *)values)[i] = fpm_time(c);
        else
            rc = fpm_get(c, fn, mask, &vr[i], 1, (double *)values + i, type, layout, type_names);
        if (rc > FPM_WARNING) return rc;
        if (rc > worst) worst = rc;
    }
    return worst;
}

int fpm_get(fpm_instance *c, const char *fn, int mask, const unsigned vr[], size_t n,
            void *values, int type, int layout, const char *const type_names[4])
{
    fpm_values *v;
    size_t i;
    int worst = FPM_OK;
    GUARD(c, fn, mask);
    if (names_time(c, vr, n))
        return get_with_time(c, fn, mask, vr, n, values, type, layout, type_names);
    if (!ACCESS(c, fn, vr, n, values, type, 0, type_names)) return FPM_ERROR;
    v = fpm_model_values(c->m);
    for (i = 0; i < n; i++) {
        double x = v->real[vr[i]];
        if (fpm_vars[vr[i]].causality == FPM_OUTPUT || fpm_vars[vr[i]].causality == FPM_LOCAL) {
            int rc = fpm_vars[vr[i]].causality == FPM_OUTPUT
                         ? fpm_model_get_output(c->m, &c->lg, vr[i], &x)
                         : fpm_model_get_local(c->m, &c->lg, vr[i], &x);
            if (rc > FPM_WARNING) return rc;
            if (rc > worst) worst = rc;
        }
        switch (layout) {
        case FPM_C_DOUBLE: ((double *)values)[i] = x; break;
        case FPM_C_INT: ((int *)values)[i] = type == FPM_BOOLEAN ? x != 0.0 : (int)x; break;
        case FPM_C_BOOL: ((unsigned char *)values)[i] = x != 0.0; break;
        default: ((const char **)values)[i] = v->string[vr[i]]; break;
        }
    }
    return worst;
}

int fpm_set(fpm_instance *c, const char *fn, int mask, const unsigned vr[], size_t n,
            const void *values, int type, int layout, const char *const type_names[4])
{
    fpm_values *v;
    size_t i;
    GUARD(c, fn, mask);
    if (names_time(c, vr, n)) {              /* FMI 3.0, section 2.4.7.4: not to be set */
        fpm_log(&c->lg, FPM_ERROR, "%s: time (value reference %ld) is the independent variable: "
                "it cannot be set (it is startTime of EnterInitializationMode, then the time "
                "SetTime sets in Model Exchange, the time doStep reaches in co-simulation); "
                "nothing was set", fn, c->time_vr);
        return FPM_ERROR;
    }
    if (!ACCESS(c, fn, vr, n, values, type, 1, type_names)) return FPM_ERROR;
    if (layout == FPM_C_STRING)               /* every string checked before any is set */
        for (i = 0; i < n; i++) {
            const char *s = ((const char *const *)values)[i];
            if (s == NULL || strlen(s) >= FPM_STR_MAX) {
                fpm_log(&c->lg, FPM_ERROR, "%s: the value of %s is %s (at most %d characters)",
                        fn, fpm_vars[vr[i]].name, s ? "too long" : "NULL", FPM_STR_MAX - 1);
                return FPM_ERROR;
            }
        }
    v = fpm_model_values(c->m);
    for (i = 0; i < n; i++) {
        switch (layout) {
        case FPM_C_DOUBLE: v->real[vr[i]] = ((const double *)values)[i]; break;
        case FPM_C_INT:
            v->real[vr[i]] = type == FPM_BOOLEAN ? (((const int *)values)[i] ? 1.0 : 0.0)
                                                 : (double)((const int *)values)[i];
            break;
        case FPM_C_BOOL: v->real[vr[i]] = ((const unsigned char *)values)[i] ? 1.0 : 0.0; break;
        default: {                            /* the host may hand back our own buffer */
            const char *src = ((const char *const *)values)[i];
            memmove(v->string[vr[i]], src, strlen(src) + 1);
            break;
        }
        }
    }
    return FPM_OK;
}

int fpm_set_input_derivatives(fpm_instance *c, const char *fn, int mask, const unsigned vr[],
                              size_t n, const int order[], const double values[])
{
    static const char *const TYPES[4] = {"Real", "Integer", "Boolean", "String"};
    size_t i;
    INTERFACE(c, fn, FPM_COSIMULATION);
    GUARD(c, fn, mask);
    if (!ACCESS(c, fn, vr, n, values, FPM_REAL, 1, TYPES)) return FPM_ERROR;
    if (n > 0 && order == NULL) return fpm_refuse(c, FPM_ERROR, fn, "the order array is NULL");
    for (i = 0; i < n; i++)
        if (fpm_vars[vr[i]].causality != FPM_INPUT) {
            fpm_log(&c->lg, FPM_ERROR, "%s: %s is not an input", fn, fpm_vars[vr[i]].name);
            return FPM_ERROR;
        }
    for (i = 0; i < n; i++) {
        int rc = fpm_model_set_input_derivative(c->m, &c->lg, vr[i], order[i], values[i]);
        if (rc != FPM_OK) return rc;
    }
    return FPM_OK;
}

/* ------------------------------------------------------------------ doStep */
int fpm_do_step(fpm_instance *c, const char *fn, int mask, double t, double h)
{
    double own;
    int rc;
    INTERFACE(c, fn, FPM_COSIMULATION);
    GUARD(c, fn, mask);
    if (!(h > 0.0) || !isfinite(h) || !isfinite(t) || !isfinite(t + h)) {
        fpm_log(&c->lg, FPM_DISCARD, "%s: communicationStepSize = %.17g at t = %.17g: the step "
                "must be positive and finite, and the time finite; step rejected, state "
                "unchanged", fn, h, t);
        return FPM_DISCARD;
    }
    if (!(t + h > t)) {
        fpm_log(&c->lg, FPM_DISCARD, "%s: communicationStepSize = %.17g is below the resolution "
                "of the time t = %.17g (t + h == t): the FMU's time cannot advance by it; step "
                "rejected, state unchanged", fn, h, t);
        return FPM_DISCARD;
    }
    own = fpm_model_time(c->m);
    if (!(fabs(t - own) <= FPM_TIME_RTOL * (fabs(own) > 1.0 ? fabs(own) : 1.0))) {
        fpm_log(&c->lg, FPM_ERROR, "%s called at t = %.17g but the FMU is at t = %.17g; restore "
                "a saved FMU state to step from another time", fn, t, own);
        return FPM_ERROR;
    }
    if (!(t + h > own)) {
        fpm_log(&c->lg, FPM_DISCARD, "%s: the step from t = %.17g over %.17g ends before the FMU's "
                "time %.17g: nothing to integrate; step rejected, state unchanged", fn, t, h, own);
        return FPM_DISCARD;
    }
    rc = fpm_model_step(c->m, &c->lg, t, h);
    c->discarded = rc == FPM_DISCARD;
    return rc;
}

/* ------------------------------------------------------------------ FMU states */
/* The model's identity in every state's header: a constant of the build, hashed once per
 * instance (fpm_instance.identity) rather than at every get and set. */
static unsigned long long identity(void)
{
    unsigned long long h = 14695981039346656037ULL;
    unsigned f = FORMAT;
    h = fpm_hash(fpm_model_name, strlen(fpm_model_name), h);
    h = fpm_hash(fpm_token, strlen(fpm_token), h);
    return fpm_hash(&f, sizeof f, h);
}

static void put_u64_at(unsigned char *p, unsigned long long v)
{
    int i;
    for (i = 0; i < 8; i++) p[i] = (unsigned char)(v >> (8 * i));
}

static unsigned long long get_u64_at(const unsigned char *p)
{
    unsigned long long v = 0;
    int i;
    for (i = 0; i < 8; i++) v |= (unsigned long long)p[i] << (8 * i);
    return v;
}

/* The FNV-1a trailer of a serialised state of n bytes (the last 8 bytes). */
static void put_trailer(unsigned char *out, size_t n)
{
    put_u64_at(out + n - 8u, fpm_hash(out, n - 8u, 14695981039346656037ULL));
}

/* The checksum of an in-memory state's n bytes: eight lanes of 8-byte words (an FNV-1a step on
 * the word, its high half folded down so that every bit reaches the next multiplication; eight,
 * so that the lanes' chains of multiplications overlap: an implicit master sums a state at
 * every get and every set), then the last whole words one to a lane, the bytes left over
 * byte-wise, the lanes and the length combined and mixed.
 * Not portable across byte orders: it never leaves the process. */
#define SUM_MIX(l, x, shift)                                                                  \
    do {                                                                                      \
        (l) = ((l) ^ (x)) * 1099511628211ULL;                                                 \
        (l) ^= (l) >> (shift);                                                                \
    } while (0)
static unsigned long long memory_sum(const unsigned char *p, size_t n)
{
    /* the eight lanes are eight variables, not an array: they stay in registers (an array's
     * lanes went through memory, and each multiplication waited for a store to be read back) */
    unsigned long long l0 = 14695981039346656037ULL, l1 = l0 + 1u, l2 = l0 + 2u, l3 = l0 + 3u;
    unsigned long long l4 = l0 + 4u, l5 = l0 + 5u, l6 = l0 + 6u, l7 = l0 + 7u, w[8], h;
    size_t i = 0, r;
    for (; i + sizeof w <= n; i += sizeof w) {
        memcpy(w, p + i, sizeof w);
        SUM_MIX(l0, w[0], 32);
        SUM_MIX(l1, w[1], 32);
        SUM_MIX(l2, w[2], 32);
        SUM_MIX(l3, w[3], 32);
        SUM_MIX(l4, w[4], 32);
        SUM_MIX(l5, w[5], 32);
        SUM_MIX(l6, w[6], 32);
        SUM_MIX(l7, w[7], 32);
    }
    r = (n - i) / sizeof w[0];                   /* the last whole words, one to a lane */
    memcpy(w, p + i, r * sizeof w[0]);
    if (r > 0) SUM_MIX(l0, w[0], 32);
    if (r > 1) SUM_MIX(l1, w[1], 32);
    if (r > 2) SUM_MIX(l2, w[2], 32);
    if (r > 3) SUM_MIX(l3, w[3], 32);
    if (r > 4) SUM_MIX(l4, w[4], 32);
    if (r > 5) SUM_MIX(l5, w[5], 32);
    if (r > 6) SUM_MIX(l6, w[6], 32);
    i += r * sizeof w[0];
    h = fpm_hash(p + i, n - i, (unsigned long long)n);
    SUM_MIX(h, l0, 29);
    SUM_MIX(h, l1, 29);
    SUM_MIX(h, l2, 29);
    SUM_MIX(h, l3, 29);
    SUM_MIX(h, l4, 29);
    SUM_MIX(h, l5, 29);
    SUM_MIX(h, l6, 29);
    SUM_MIX(h, l7, 29);
    return h;
}

/* The instance serialised into out (cap bytes), its trailer left zero (put_trailer writes it);
 * the size, or 0 if it does not fit. */
static size_t serialize(const fpm_instance *c, unsigned char *out, size_t cap)
{
    fpm_writer w;
    const fpm_values *v = fpm_model_values(c->m);
    int i;
    size_t payload;
    if (cap < HEADER + 8u) return 0;
    w.p = out;
    w.cap = cap - 8u;
    w.n = HEADER;
    fpm_put_i32(&w, c->mode | c->interface << 8);   /* the mode and the interface */
    fpm_put_i32(&w, c->discarded);
    for (i = 0; i < FPM_MAX_VARS; i++) {
        const fpm_var *var = &fpm_vars[i];
        if (var->name == NULL || var->causality == FPM_OUTPUT || var->causality == FPM_LOCAL)
            continue;
        if (var->type == FPM_STRING) fpm_put_str(&w, v->string[i]);
        else fpm_put_f64(&w, v->real[i]);
    }
    fpm_model_save(c->m, &w);
    if (w.n > w.cap) return 0;
    payload = w.n - HEADER;
    memcpy(out, MAGIC, 4);
    out[4] = (unsigned char)FORMAT;
    out[5] = out[6] = out[7] = 0;
    put_u64_at(out + 8, (unsigned long long)payload);
    put_u64_at(out + 16, c->identity);
    put_u64_at(out + w.n, 0);
    return w.n + 8u;
}

/* Read serialised bytes into the spare model, checking everything (the FNV-1a trailer only when
 * `trailer`: an in-memory state's bytes are guarded by their memory_sum instead); the mode and
 * flag in *mode, *discarded. FPM_OK, or FPM_ERROR with the reason logged. */
static int restore_into_spare(fpm_instance *c, const char *fn, const unsigned char *in, size_t n,
                              int trailer, int *mode, int *discarded)
{
    fpm_reader r;
    fpm_values *v;
    size_t payload;
    int i, need;
    if (in == NULL || n < HEADER + 8u || memcmp(in, MAGIC, 4) != 0) {
        fpm_log(&c->lg, FPM_ERROR, "%s: not a serialised FMU state of %s (%lu bytes, no header)",
                fn, fpm_model_name, (unsigned long)n);
        return FPM_ERROR;
    }
    if (in[4] != FORMAT || in[5] || in[6] || in[7]) {
        fpm_log(&c->lg, FPM_ERROR, "%s: serialised FMU state of format version %u; this FMU "
                "reads %u", fn, (unsigned)in[4] | (unsigned)in[5] << 8, FORMAT);
        return FPM_ERROR;
    }
    payload = (size_t)get_u64_at(in + 8);
    if (payload != n - HEADER - 8u) {
        fpm_log(&c->lg, FPM_ERROR, "%s: serialised FMU state of %lu bytes; its header says "
                "%lu bytes", fn, (unsigned long)n, (unsigned long)(get_u64_at(in + 8) + HEADER + 8u));
        return FPM_ERROR;
    }
    if (get_u64_at(in + 16) != c->identity) {
        fpm_log(&c->lg, FPM_ERROR, "%s: the serialised FMU state belongs to another model or "
                "build (this is %s, token %s)", fn, fpm_model_name, fpm_token);
        return FPM_ERROR;
    }
    if (trailer && get_u64_at(in + n - 8u) != fpm_hash(in, n - 8u, 14695981039346656037ULL)) {
        fpm_log(&c->lg, FPM_ERROR, "%s: the serialised FMU state is corrupt (its checksum does "
                "not match its bytes)", fn);
        return FPM_ERROR;
    }
    memset(&r, 0, sizeof r);
    r.interface = c->interface;
    r.p = in + HEADER;
    r.n = payload;
    fpm_model_reset(c->spare, 0.0);
    v = fpm_model_values(c->spare);
    if (fpm_get_i32(&r, "the mode", mode)) {
        /* the mode in the low byte, the interface above it: a state of one interface never
         * restores into an instance of the other (Model Exchange leaves the co-simulation
         * stepper's data as they were, which a co-simulation step would trust) */
        int raw = *mode, iface = (int)((unsigned)raw >> 8);
        *mode = (int)((unsigned)raw & 0xffu);
        if (!(*mode > 0 && (*mode & (*mode - 1)) == 0 && (*mode & c->modes)))
            fpm_reject(&r, "the mode %d is not a state this instance can be in", raw);
        else if (iface != c->interface)
            fpm_reject(&r, "a state of an instance of %s; this instance is of %s",
                       interface_name(iface), interface_name(c->interface));
    }
    fpm_get_int_in(&r, "the refusal flag", 0, 1, discarded);
    if (r.why[0] == '\0' && *discarded && !(*mode & (FPM_STEP | FPM_EVENT | FPM_TERMINATED)))
        fpm_reject(&r, "a refused step in state %s", fpm_mode_name(*mode));
    for (i = 0; i < FPM_MAX_VARS && r.why[0] == '\0'; i++) {
        const fpm_var *var = &fpm_vars[i];
        double x;
        if (var->name == NULL || var->causality == FPM_OUTPUT || var->causality == FPM_LOCAL)
            continue;
        if (var->type == FPM_STRING) {
            fpm_get_str(&r, var->name, v->string[i], FPM_STR_MAX);
            continue;
        }
        if (!fpm_get_f64(&r, var->name, &x)) break;
        if (var->type == FPM_INTEGER && !(x >= -2147483648.0 && x <= 2147483647.0 && x == floor(x)))
            fpm_reject(&r, "%s = %g is not an Integer value", var->name, x);
        if (var->type == FPM_BOOLEAN && x != 0.0 && x != 1.0)
            fpm_reject(&r, "%s = %g is not a Boolean value", var->name, x);
        v->real[i] = x;
    }
    need = (*mode & (FPM_STEP | FPM_EVENT | FPM_CONTINUOUS)) ? 1
           : (*mode & (FPM_INSTANTIATED | FPM_INIT | FPM_ERROR_MODE)) ? 0 : -1;
    if (r.why[0] == '\0') fpm_model_load(c->spare, &r, need, c->m);
    if (r.why[0] == '\0' && r.pos != r.n)
        fpm_reject(&r, "%lu bytes are left over", (unsigned long)(r.n - r.pos));
    if (r.why[0] != '\0') {
        fpm_log(&c->lg, FPM_ERROR, "%s: the FMU state is not a valid state of %s: %s; the "
                "instance is unchanged", fn, fpm_model_name, r.why);
        return FPM_ERROR;
    }
    return FPM_OK;
}

static state *new_state(size_t cap)
{
    state *s = (state *)malloc(offsetof(state, data) + cap);
    if (s == NULL) return NULL;
    s->magic = STATE_MAGIC;
    s->n = 0;
    s->cap = cap;
    return s;
}

static const state *known(fpm_instance *c, const char *fn, const void *p)
{
    const state *s = (const state *)p;
    if (s == NULL) {
        fpm_log(&c->lg, FPM_ERROR, "%s: the FMU state is NULL", fn);
        return NULL;
    }
    if (s->magic != STATE_MAGIC || s->n > s->cap) {
        fpm_log(&c->lg, FPM_ERROR, "%s: not an FMU state of this FMU (or one freed already)", fn);
        return NULL;
    }
    return s;
}

/* A known state (known) whose bytes are intact (their memory_sum), or NULL with the reason
 * logged. */
static const state *intact(fpm_instance *c, const char *fn, const void *p)
{
    const state *s = known(c, fn, p);
    if (s != NULL && (s->n < HEADER + 8u || memory_sum(s->data, s->n - 8u) != s->sum)) {
        fpm_log(&c->lg, FPM_ERROR, "%s: the FMU state is corrupt (its checksum does not match "
                "its bytes: the state's memory was overwritten)", fn);
        return NULL;
    }
    return s;
}

/* n (>= HEADER + 8) bytes of a serialised state into *out, with their memory_sum: the state given
 * (FMI: it is overwritten) when it is large enough, else a state of its own size that replaces
 * it. */
static int store(fpm_instance *c, const char *fn, void **out, const unsigned char *data,
                 size_t n)
{
    state *s = (state *)*out;
    if (s == NULL || s->cap < n) {
        state *fresh = new_state(n);
        if (fresh == NULL) return fpm_refuse(c, FPM_ERROR, fn, "out of memory");
        if (s != NULL) {
            s->magic = 0;
            free(s);
        }
        s = fresh;
    }
    memcpy(s->data, data, n);
    s->n = n;
    s->sum = memory_sum(s->data, n - 8u);
    *out = s;
    return FPM_OK;
}

int fpm_get_state(fpm_instance *c, const char *fn, int mask, void **out)
{
    size_t n;
    GUARD(c, fn, mask);
    if (out == NULL) return fpm_refuse(c, FPM_ERROR, fn, "the pointer to the state is NULL");
    if (*out != NULL && known(c, fn, *out) == NULL) return FPM_ERROR;
    n = serialize(c, c->scratch, c->state_cap);
    if (n == 0) return fpm_refuse(c, FPM_ERROR, fn, "the state does not fit its buffer (a bug)");
    return store(c, fn, out, c->scratch, n);
}

/* Make the spare model the live one. */
static void commit(fpm_instance *c, int mode, int discarded)
{
    fpm_model *m = c->m;
    c->m = c->spare;
    c->spare = m;
    c->mode = mode;
    c->discarded = discarded;
}

int fpm_set_state(fpm_instance *c, const char *fn, int mask, const void *p)
{
    const state *s;
    int mode, discarded;
    GUARD(c, fn, mask);
    if ((s = intact(c, fn, p)) == NULL) return FPM_ERROR;
    if (restore_into_spare(c, fn, s->data, s->n, 0, &mode, &discarded) != FPM_OK)
        return FPM_ERROR;
    fpm_model_keep(c->spare, c->m);
    commit(c, mode, discarded);
    return FPM_OK;
}

int fpm_free_state(fpm_instance *c, const char *fn, int mask, void **p)
{
    state *s;
    GUARD(c, fn, mask);
    if (p == NULL || *p == NULL) return FPM_OK;
    if (known(c, fn, *p) == NULL) return FPM_ERROR;
    s = (state *)*p;
    s->magic = 0;
    free(s);
    *p = NULL;
    return FPM_OK;
}

int fpm_state_size(fpm_instance *c, const char *fn, int mask, const void *p, size_t *size)
{
    const state *s;
    GUARD(c, fn, mask);
    if (size == NULL) return fpm_refuse(c, FPM_ERROR, fn, "size is NULL");
    if ((s = known(c, fn, p)) == NULL) return FPM_ERROR;
    *size = s->n;
    return FPM_OK;
}

int fpm_serialize_state(fpm_instance *c, const char *fn, int mask, const void *p,
                        unsigned char *data, size_t size)
{
    const state *s;
    GUARD(c, fn, mask);
    if ((s = intact(c, fn, p)) == NULL) return FPM_ERROR;
    if (data == NULL || size < s->n) {
        fpm_log(&c->lg, FPM_ERROR, "%s: need a buffer of %lu bytes, got %lu%s", fn,
                (unsigned long)s->n, (unsigned long)size, data == NULL ? " (NULL)" : "");
        return FPM_ERROR;
    }
    memcpy(data, s->data, s->n);
    put_trailer(data, s->n);
    return FPM_OK;
}

int fpm_deserialize_state(fpm_instance *c, const char *fn, int mask, const unsigned char *data,
                          size_t size, void **out)
{
    int mode, discarded;
    GUARD(c, fn, mask);
    if (out == NULL) return fpm_refuse(c, FPM_ERROR, fn, "the pointer to the state is NULL");
    if (*out != NULL && known(c, fn, *out) == NULL) return FPM_ERROR;
    if (data != NULL && size > c->state_cap) {
        fpm_log(&c->lg, FPM_ERROR, "%s: serialised FMU state of %lu bytes; a state of %s has at "
                "most %lu", fn, (unsigned long)size, fpm_model_name, (unsigned long)c->state_cap);
        return FPM_ERROR;
    }
    /* the whole check, by restoring it into the spare model (the live one is not touched) */
    if (restore_into_spare(c, fn, data, size, 1, &mode, &discarded) != FPM_OK) return FPM_ERROR;
    return store(c, fn, out, data, size);
}

/* ------------------------------------------------------------------ Model Exchange */
/* The array of a Model-Exchange call: not NULL (when n > 0), and exactly `want` values. */
static int me_array(fpm_instance *c, const char *fn, const char *what, const void *p, size_t n,
                    size_t want)
{
    if (n != want) {
        fpm_log(&c->lg, FPM_ERROR, "%s: %lu %s asked for; %s has %lu", fn, (unsigned long)n,
                what, fpm_model_name, (unsigned long)want);
        return 0;
    }
    if (n > 0 && p == NULL) {
        fpm_log(&c->lg, FPM_ERROR, "%s: the array of %s is NULL", fn, what);
        return 0;
    }
    return 1;
}

/* Before exitInitializationMode (initialization mode: the initial unknowns): the states,
 * derivatives (kind 1) or event indicators (kind 2) one by one through their variables, which
 * the model computes from the parameters as they are, as it does the outputs. */
static int from_variables(fpm_instance *c, const char *fn, int kind, double out[], size_t n)
{
    unsigned vr;
    int rc, worst = FPM_OK;
    for (vr = 0; vr < FPM_MAX_VARS; vr++) {
        const fpm_var *v = &fpm_vars[vr];
        int at = v->name == NULL ? 0 : kind == 0 ? v->state : kind == 1 ? v->der : v->indicator;
        if (at <= 0 || (size_t)at > n) continue;
        rc = v->causality == FPM_OUTPUT ? fpm_model_get_output(c->m, &c->lg, vr, &out[at - 1])
                                         : fpm_model_get_local(c->m, &c->lg, vr, &out[at - 1]);
        if (rc > FPM_WARNING) return fpm_refuse(c, rc, fn, "not available before "
                                                "initialisation with these parameters (above)");
        if (rc > worst) worst = rc;
    }
    return worst;
}

int fpm_me_set_time(fpm_instance *c, const char *fn, int mask, double t)
{
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    if (!isfinite(t)) {
        fpm_log(&c->lg, FPM_ERROR, "%s: time = %.17g is not finite", fn, t);
        return FPM_ERROR;
    }
    return fpm_model_set_time(c->m, &c->lg, t);
}

int fpm_me_set_states(fpm_instance *c, const char *fn, int mask, const double x[], size_t nx)
{
    size_t i;
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    if (!me_array(c, fn, "states", x, nx, fpm_model_nx())) return FPM_ERROR;
    for (i = 0; i < nx; i++)
        if (!isfinite(x[i])) {
            fpm_log(&c->lg, FPM_ERROR, "%s: state %lu = %g is not finite; the states are "
                    "unchanged", fn, (unsigned long)i, x[i]);
            return FPM_ERROR;
        }
    return fpm_model_set_states(c->m, &c->lg, x);
}

int fpm_me_get_states(fpm_instance *c, const char *fn, int mask, double x[], size_t nx)
{
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    if (!me_array(c, fn, "states", x, nx, fpm_model_nx())) return FPM_ERROR;
    if (!fpm_model_initialized(c->m)) return from_variables(c, fn, 0, x, nx);
    fpm_model_get_states(c->m, x);
    return FPM_OK;
}

int fpm_me_get_derivatives(fpm_instance *c, const char *fn, int mask, double dx[], size_t nx)
{
    size_t i;
    int rc;
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    if (!me_array(c, fn, "derivatives", dx, nx, fpm_model_nx())) return FPM_ERROR;
    rc = fpm_model_initialized(c->m) ? fpm_model_derivatives(c->m, &c->lg, dx)
                                     : from_variables(c, fn, 1, dx, nx);
    if (rc > FPM_WARNING) return rc;
    for (i = 0; i < nx; i++)                  /* never: the model checks them */
        if (!isfinite(dx[i])) return fpm_refuse(c, FPM_ERROR, fn, "a derivative is not finite");
    return rc;
}

int fpm_me_get_nominals(fpm_instance *c, const char *fn, int mask, double x[], size_t nx)
{
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    if (!me_array(c, fn, "nominals", x, nx, fpm_model_nx())) return FPM_ERROR;
    if (!fpm_model_initialized(c->m)) {       /* before initialisation: the default, 1 */
        size_t i;
        for (i = 0; i < nx; i++) x[i] = 1.0;
        return FPM_OK;
    }
    fpm_model_nominals(c->m, x);
    return FPM_OK;
}

int fpm_me_get_event_indicators(fpm_instance *c, const char *fn, int mask, double z[], size_t nz)
{
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    if (!me_array(c, fn, "event indicators", z, nz, fpm_model_nz())) return FPM_ERROR;
    if (nz == 0) return FPM_OK;
    if (!fpm_model_initialized(c->m)) return from_variables(c, fn, 2, z, nz);
    return fpm_model_event_indicators(c->m, &c->lg, z);
}

/* The model's event update, each event's message once. An importer may ask about the same
 * event more than once: completedIntegratorStep, then (it asks to terminate, but the importer
 * handles the state event it located anyway) event mode and NewDiscreteStates /
 * UpdateDiscreteStates at the same time and state; and the event iteration itself repeats the
 * update. The model's warning names the event (the time and the value that reached its bound,
 * to 17 digits): the same warning again is the same event, answered as before (terminate) but
 * with status OK and no second message. A different time or state is another event, said
 * anew. */
static void event_emit(void *env, int status, const char *category, const char *message)
{
    fpm_instance *c = (fpm_instance *)env;
    if (status == FPM_WARNING) {
        if (strcmp(message, c->event_said) == 0) {
            c->event_repeat = 1;
            return;
        }
        strncpy(c->event_said, message, FPM_MSG_MAX - 1);
        c->event_said[FPM_MSG_MAX - 1] = '\0';
    }
    c->host_emit(c, status, category, message);
}

static int event_update(fpm_instance *c, int *terminate)
{
    fpm_logger lg;
    int rc;
    lg.emit = event_emit;
    lg.env = c;
    *terminate = 0;
    c->event_repeat = 0;
    rc = fpm_model_event_update(c->m, &lg, terminate);
    if (rc == FPM_WARNING && c->event_repeat) rc = FPM_OK;          /* said before */
    return rc;
}

int fpm_me_update_discrete(fpm_instance *c, const char *fn, int mask, int *terminate)
{
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    return event_update(c, terminate);
}

int fpm_me_completed_step(fpm_instance *c, const char *fn, int mask, int *terminate)
{
    INTERFACE(c, fn, FPM_MODEL_EXCHANGE);
    GUARD(c, fn, mask);
    /* an importer that does not locate events is told here that a bound was crossed */
    return event_update(c, terminate);
}

/* ------------------------------------------------------------------ directional derivatives */
/* Where vr sits in the linearisation [[A, B], [C, D]]: as an unknown its row (a derivative:
 * its state's row of A and B; an output: nx + its index among the outputs), as a known its
 * column (a state: its column of A and C; an input: nx + its index among the inputs); -1 if it
 * is not of that kind. */
static int jac_row(const fpm_instance *c, unsigned vr)
{
    const fpm_var *v;
    if (vr >= FPM_MAX_VARS || (v = &fpm_vars[vr])->name == NULL || v->type != FPM_REAL) return -1;
    if (v->der && c->interface == FPM_MODEL_EXCHANGE) return v->der - 1;
    if (v->causality == FPM_OUTPUT) return (int)fpm_model_nx() + index_among(vr, FPM_OUTPUT);
    return -1;
}

static int jac_col(unsigned vr)
{
    const fpm_var *v;
    if (vr >= FPM_MAX_VARS || (v = &fpm_vars[vr])->name == NULL || v->type != FPM_REAL) return -1;
    if (v->state) return v->state - 1;
    if (v->causality == FPM_INPUT) return (int)fpm_model_nx() + index_among(vr, FPM_INPUT);
    return -1;
}

int fpm_directional_derivative(fpm_instance *c, const char *fn, int mask,
                               const unsigned unknowns[], size_t n_unknowns,
                               const unsigned knowns[], size_t n_knowns, const double seed[],
                               double sensitivity[])
{
    size_t i, j, nx = fpm_model_nx(), nu = (size_t)count_vars(FPM_INPUT);
    size_t ny = (size_t)count_vars(FPM_OUTPUT);
    int want_ab = 0, want_cd = 0, rc;
    GUARD(c, fn, mask);
    if (!fpm_model_offers_jacobian()) {
        fpm_log(&c->lg, FPM_ERROR, "%s: %s provides no directional derivatives (its "
                "modelDescription says providesDirectionalDerivative = false)", fn,
                fpm_model_name);
        return FPM_ERROR;
    }
    if ((n_unknowns > 0 && (unknowns == NULL || sensitivity == NULL)) ||
        (n_knowns > 0 && (knowns == NULL || seed == NULL)))
        return fpm_refuse(c, FPM_ERROR, fn, "an array is NULL but its length is not 0");
    for (i = 0; i < n_unknowns; i++) {
        int r = jac_row(c, unknowns[i]);
        if (r < 0) {
            int k = fpm_lookup(unknowns[i]);
            fpm_log(&c->lg, FPM_ERROR, "%s: unknown %u (%s) is not %s", fn, (unsigned)unknowns[i],
                    k < 0 ? "no variable" : fpm_vars[k].name,
                    c->interface == FPM_MODEL_EXCHANGE ? "a state derivative or an output"
                                                        : "an output");
            return FPM_ERROR;
        }
        if ((size_t)r < nx) want_ab = 1;
        else want_cd = 1;
    }
    for (j = 0; j < n_knowns; j++)
        if (jac_col(knowns[j]) < 0) {
            int k = fpm_lookup(knowns[j]);
            fpm_log(&c->lg, FPM_ERROR, "%s: known %u (%s) is not a continuous state or an input",
                    fn, (unsigned)knowns[j], k < 0 ? "no variable" : fpm_vars[k].name);
            return FPM_ERROR;
        }
    for (j = 0; j < n_knowns; j++)
        if (!isfinite(seed[j])) {
            fpm_log(&c->lg, FPM_ERROR, "%s: the seed of %s is %g (not finite)", fn,
                    fpm_vars[knowns[j]].name, seed[j]);
            return FPM_ERROR;
        }
    if (n_unknowns == 0) return FPM_OK;
    if (!fpm_model_initialized(c->m))
        return fpm_refuse(c, FPM_ERROR, fn, "the model is not initialised (no linearisation "
                          "before exitInitializationMode)");
    /* the blocks A (nx x nx), B (nx x nu), C (ny x nx), D (ny x nu), one after the other */
    {
        double *A = c->jac, *B = A + nx * nx, *C = B + nx * nu, *D = C + ny * nx;
        rc = fpm_model_jacobian(c->m, &c->lg, want_ab ? A : NULL, want_ab ? B : NULL,
                                want_cd ? C : NULL, want_cd ? D : NULL);
        if (rc > FPM_WARNING) return rc;
        for (i = 0; i < n_unknowns; i++) {
            size_t r = (size_t)jac_row(c, unknowns[i]);
            double acc = 0.0;
            for (j = 0; j < n_knowns; j++) {
                size_t k = (size_t)jac_col(knowns[j]);
                double a = r < nx ? (k < nx ? A[r * nx + k] : B[r * nu + (k - nx)])
                                  : (k < nx ? C[(r - nx) * nx + k] : D[(r - nx) * nu + (k - nx)]);
                acc += a * seed[j];
            }
            if (!isfinite(acc)) {
                fpm_log(&c->lg, FPM_ERROR, "%s: the sensitivity of %s is not finite", fn,
                        fpm_vars[unknowns[i]].name);
                return FPM_ERROR;
            }
            sensitivity[i] = acc;
        }
    }
    return rc;
}

/* ------------------------------------------------------------------ output derivatives */
int fpm_output_derivatives(fpm_instance *c, const char *fn, int mask, const unsigned vr[],
                           size_t n, const int order[], double values[])
{
    size_t i;
    int max = fpm_model_max_output_derivative_order();
    INTERFACE(c, fn, FPM_COSIMULATION);
    GUARD(c, fn, mask);
    if (n > 0 && (vr == NULL || order == NULL || values == NULL))
        return fpm_refuse(c, FPM_ERROR, fn, "an array is NULL but its length is not 0");
    for (i = 0; i < n; i++) {
        int k = fpm_lookup(vr[i]);
        if (k < 0 || fpm_vars[k].causality != FPM_OUTPUT || fpm_vars[k].type != FPM_REAL) {
            fpm_log(&c->lg, FPM_ERROR, "%s: value reference %u (%s) is not a Real output", fn,
                    (unsigned)vr[i], k < 0 ? "no variable" : fpm_vars[k].name);
            return FPM_ERROR;
        }
        if (max == 0) {
            fpm_log(&c->lg, FPM_ERROR, "%s: %s gives no output derivatives "
                    "(maxOutputDerivativeOrder = 0)", fn, fpm_model_name);
            return FPM_ERROR;
        }
        if (order[i] < 1 || order[i] > max) {
            fpm_log(&c->lg, FPM_ERROR, "%s: order %d of %s; this FMU gives orders 1..%d "
                    "(maxOutputDerivativeOrder)", fn, order[i], fpm_vars[k].name, max);
            return FPM_ERROR;
        }
    }
    if (n > 0 && !fpm_model_initialized(c->m))
        return fpm_refuse(c, FPM_ERROR, fn, "the model is not initialised");
    if (n > 0) {
        int rc = fpm_model_output_derivatives(c->m, &c->lg, n, vr, order, values);
        if (rc > FPM_WARNING) return rc;
    }
    for (i = 0; i < n; i++) {
        if (!isfinite(values[i])) {
            fpm_log(&c->lg, FPM_ERROR, "%s: the derivative of order %d of %s is not finite", fn,
                    order[i], fpm_vars[vr[i]].name);
            return FPM_ERROR;
        }
    }
    return FPM_OK;
}
