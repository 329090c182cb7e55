/* fpm_guard.c - the guard of every FMI call (see fpm.h): logging, the mode machine, the checks
 * of value references, types, causalities and arrays against the generated table, and the
 * serialisation primitives. No model: the pythonfmu loader links it too. */
#include "fpm.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

const char *const fpm_log_categories[FPM_N_CATEGORIES] = {
    "logAll", "logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal"};

int fpm_log_category(const char *name)
{
    int k;
    if (name == NULL) return -1;
    for (k = 0; k < FPM_N_CATEGORIES; k++)
        if (strcmp(name, fpm_log_categories[k]) == 0) return k;
    return -1;
}

void fpm_log(const fpm_logger *lg, int status, const char *fmt, ...)
{
    char msg[FPM_MSG_MAX];
    size_t i;
    va_list ap;
    if (lg == NULL || lg->emit == NULL) return;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    /* hosts may pass the message to printf as a format: no '%' goes out; and hosts decode it
     * as UTF-8: a value echoed from the host (a string parameter) goes out as ASCII */
    for (i = 0; msg[i] != '\0'; i++) {
        unsigned char ch = (unsigned char)msg[i];
        if (ch == '%') msg[i] = '#';
        else if (ch < 0x20 || ch > 0x7e) msg[i] = '?';
    }
    if (status < FPM_OK || status > FPM_FATAL) status = FPM_FATAL;
    lg->emit(lg->env, status, fpm_log_categories[status], msg);
}

const char *fpm_mode_name(int mode)
{
    switch (mode) {
    case FPM_INSTANTIATED: return "Instantiated";
    case FPM_INIT: return "InitializationMode";
    case FPM_EVENT: return "EventMode";
    case FPM_CONTINUOUS: return "ContinuousTimeMode";
    case FPM_STEP: return "StepMode";
    case FPM_TERMINATED: return "Terminated";
    case FPM_FATAL_MODE: return "Fatal (unusable after an internal error: free it)";
    default: return "Error";
    }
}

int fpm_allowed(const fpm_logger *lg, const char *fn, int mode, int mask)
{
    if (mode & mask) return 1;
    fpm_log(lg, FPM_ERROR, "%s is not allowed in state %s", fn, fpm_mode_name(mode));
    return 0;
}

int fpm_lookup(unsigned vr)
{
    if (vr >= FPM_MAX_VARS || fpm_vars[vr].name == NULL) return -1;
    return (int)vr;
}

int fpm_check_access(const fpm_logger *lg, const char *fn, int mode, const unsigned vr[],
                     size_t n, const void *values, int type, int set,
                     const char *const type_names[4])
{
    size_t i;
    if (n == 0) return 1;
    if (vr == NULL || values == NULL) {
        fpm_log(lg, FPM_ERROR, "%s: %s is NULL but %lu values are asked for", fn,
                vr == NULL ? "the value reference array" : "the value array", (unsigned long)n);
        return 0;
    }
    for (i = 0; i < n; i++) {
        const fpm_var *v;
        int k = fpm_lookup(vr[i]);
        if (k < 0) {
            fpm_log(lg, FPM_ERROR, "%s: %s has no variable with value reference %u", fn,
                    fpm_model_name, vr[i]);
            return 0;
        }
        v = &fpm_vars[k];
        if (v->type != type) {
            fpm_log(lg, FPM_ERROR, "%s: variable %s (value reference %u) is of type %s, not %s",
                    fn, v->name, vr[i], type_names[v->type], type_names[type]);
            return 0;
        }
        if (!set) continue;
        if (v->causality == FPM_OUTPUT) {
            fpm_log(lg, FPM_ERROR, "%s: %s is an output; it cannot be set", fn, v->name);
            return 0;
        }
        if (v->causality == FPM_LOCAL) {
            fpm_log(lg, FPM_ERROR, "%s: %s is calculated (a Model-Exchange local); it cannot be "
                    "set%s", fn, v->name, v->state ? " (states: SetContinuousStates)" : "");
            return 0;
        }
        if (v->causality == FPM_PARAMETER && !(mode & FPM_MASK_SET_PARAMETER)) {
            fpm_log(lg, FPM_ERROR, "%s: parameter %s is fixed: it can only be set before "
                    "exitInitializationMode (state: %s)", fn, v->name, fpm_mode_name(mode));
            return 0;
        }
    }
    return 1;
}

void fpm_start_values(fpm_values *v)
{
    int i;
    for (i = 0; i < FPM_MAX_VARS; i++) {
        const fpm_var *var = &fpm_vars[i];
        if (var->name == NULL || var->causality == FPM_OUTPUT || var->causality == FPM_LOCAL)
            continue;
        if (var->type == FPM_STRING) {
            strncpy(v->string[i], var->start_string, FPM_STR_MAX - 1);
            v->string[i][FPM_STR_MAX - 1] = '\0';
        } else {
            v->real[i] = var->start_real;
        }
    }
}

unsigned long long fpm_hash(const void *data, size_t n, unsigned long long h)
{
    const unsigned char *p = (const unsigned char *)data;
    size_t i;
    for (i = 0; i < n; i++) {
        h ^= p[i];
        h *= 1099511628211ULL;
    }
    return h;
}

/* ------------------------------------------------------------------ writer and reader */
/* Items are little-endian: a double as its 64 bits, an int as 32 bits, a string as a 32-bit
 * length and its bytes (no terminating 0). The bytes of an item are spelled out one by one,
 * not in a loop: the compiler merges them into one load or store (a restore reads every item of
 * a state, and an implicit master restores several times a step). */
static void put_bytes(fpm_writer *w, const unsigned char *b, size_t k)
{
    if (w->p != NULL && w->n + k <= w->cap) memcpy(w->p + w->n, b, k);
    w->n += k;
}

static void put_u64(fpm_writer *w, unsigned long long v)
{
    unsigned char b[8];
    b[0] = (unsigned char)v;
    b[1] = (unsigned char)(v >> 8);
    b[2] = (unsigned char)(v >> 16);
    b[3] = (unsigned char)(v >> 24);
    b[4] = (unsigned char)(v >> 32);
    b[5] = (unsigned char)(v >> 40);
    b[6] = (unsigned char)(v >> 48);
    b[7] = (unsigned char)(v >> 56);
    put_bytes(w, b, 8);
}

static void put_u32(fpm_writer *w, unsigned v)
{
    unsigned char b[4];
    b[0] = (unsigned char)v;
    b[1] = (unsigned char)(v >> 8);
    b[2] = (unsigned char)(v >> 16);
    b[3] = (unsigned char)(v >> 24);
    put_bytes(w, b, 4);
}

void fpm_put_f64(fpm_writer *w, double x)
{
    unsigned long long u;
    memcpy(&u, &x, sizeof u);
    put_u64(w, u);
}

void fpm_put_i32(fpm_writer *w, int x) { put_u32(w, (unsigned)x); }

void fpm_put_str(fpm_writer *w, const char *s)
{
    size_t k = strlen(s);
    put_u32(w, (unsigned)k);
    put_bytes(w, (const unsigned char *)s, k);
}

int fpm_reject(fpm_reader *r, const char *fmt, ...)
{
    va_list ap;
    if (r->why[0] != '\0') return 0;          /* keep the first reason */
    va_start(ap, fmt);
    vsnprintf(r->why, sizeof r->why, fmt, ap);
    va_end(ap);
    return 0;
}

static void into_why(void *env, int status, const char *category, const char *message)
{
    (void)category;
    if (status > FPM_WARNING) fpm_reject((fpm_reader *)env, "%s", message);
}

fpm_logger fpm_reader_logger(fpm_reader *r)
{
    fpm_logger lg;
    lg.emit = into_why;
    lg.env = r;
    return lg;
}

static int take(fpm_reader *r, const char *what, size_t k, const unsigned char **b)
{
    if (r->why[0] != '\0') return 0;
    if (k > r->n - r->pos) return fpm_reject(r, "the data end before %s", what);
    *b = r->p + r->pos;
    r->pos += k;
    return 1;
}

int fpm_get_f64(fpm_reader *r, const char *what, double *x)
{
    const unsigned char *b = NULL;
    unsigned long long u;
    *x = 0.0;
    if (!take(r, what, 8, &b)) return 0;
    u = (unsigned long long)b[0] | (unsigned long long)b[1] << 8 |
        (unsigned long long)b[2] << 16 | (unsigned long long)b[3] << 24 |
        (unsigned long long)b[4] << 32 | (unsigned long long)b[5] << 40 |
        (unsigned long long)b[6] << 48 | (unsigned long long)b[7] << 56;
    memcpy(x, &u, sizeof u);
    return 1;
}

int fpm_get_i32(fpm_reader *r, const char *what, int *x)
{
    const unsigned char *b = NULL;
    unsigned u;
    *x = 0;
    if (!take(r, what, 4, &b)) return 0;
    u = (unsigned)b[0] | (unsigned)b[1] << 8 | (unsigned)b[2] << 16 | (unsigned)b[3] << 24;
    /* two's complement without implementation-defined conversions */
    *x = u <= 0x7fffffffu ? (int)u : -(int)(0xffffffffu - u) - 1;
    return 1;
}

int fpm_get_str(fpm_reader *r, const char *what, char *dst, size_t cap)
{
    const unsigned char *b = NULL;
    int k;
    size_t i;
    if (!fpm_get_i32(r, what, &k)) return 0;
    if (k < 0 || (size_t)k >= cap)
        return fpm_reject(r, "%s has %d characters (at most %lu)", what, k,
                          (unsigned long)(cap - 1));
    if (!take(r, what, (size_t)k, &b)) return 0;
    for (i = 0; i < (size_t)k; i++)
        if (b[i] == 0) return fpm_reject(r, "%s holds a 0 byte", what);
    memcpy(dst, b, (size_t)k);
    dst[k] = '\0';
    return 1;
}

int fpm_get_finite(fpm_reader *r, const char *what, double *x)
{
    if (!fpm_get_f64(r, what, x)) return 0;
    if (!isfinite(*x)) return fpm_reject(r, "%s = %g is not finite", what, *x);
    return 1;
}

int fpm_get_int_in(fpm_reader *r, const char *what, int lo, int hi, int *x)
{
    if (!fpm_get_i32(r, what, x)) return 0;
    if (*x < lo || *x > hi) return fpm_reject(r, "%s = %d is out of %d..%d", what, *x, lo, hi);
    return 1;
}
