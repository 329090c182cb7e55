/*
 * fuzz_fmi.c - a libFuzzer target over one native model (the one it is linked with: the
 * model's sources, the core and both FMI adapters), driving FMI 2.0 or FMI 3.0 call sequences
 * and crafted FMU states (tests/fuzz/fuzz.py builds and runs it; docs/fuzzing.md).
 *
 * An input is a program: its first byte picks the FMI version, then each byte is an operation
 * with its arguments read from the bytes that follow (doubles from a table of interesting values
 * or raw; value references, counts and NULL arrays; strings). The operations are every call of
 * the co-simulation API, every call of Model Exchange (an instance of either interface: the
 * calls of the other are refused) with directional and output derivatives, and three that
 * reach past the state's trailer: serialise the current state, edit its bytes at offsets the
 * input chooses, and recompute the checksum (or not) before deserialising and restoring it; and
 * a raw blob from the input with its checksum recomputed.
 *
 * Besides the sanitizers (address, undefined: any report is a finding) and libFuzzer's timeout
 * (a hang), the harness checks the contract of the FMUs and aborts when it is broken:
 *   - every non-OK status comes with at least one log message, with a category and no '%';
 *   - an output read with status OK (or Warning) is finite, and so are the states, derivatives,
 *     nominals (also > 0), event indicators, directional and output derivatives;
 *   - a doStep that returns OK has advanced the FMU's time to exactly t + h;
 *   - no operation (one FMI call, or the few of a state's get, edit and restore) takes more than
 *     CALL_LIMIT_S seconds of its thread's CPU time.
 */
#define _POSIX_C_SOURCE 200809L               /* clock_gettime */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"
#include "fpm.h"

/* ------------------------------------------------------------------ the input */
typedef struct input {
    const uint8_t *p;
    size_t n, i;
} input;

static int more(const input *in) { return in->i < in->n; }

static unsigned u8(input *in) { return in->i < in->n ? in->p[in->i++] : 0u; }

static unsigned u16(input *in)
{
    unsigned lo = u8(in);
    return lo | (u8(in) << 8);
}

static const double INTERESTING[] = {
    0.0, -0.0, 1.0, -1.0, 1e-3, 2.5e-4, 2e-3, 0.5, 0.3, 1.5707963267948966, 2.0, 4.0, 8.0, 9.0,
    24.0, 100.0, 101.0, 1e6, 1e-300, 5e-324, 2.2250738585072014e-308, 1e19, 1e160, 1e200, 1e300,
    1.7976931348623157e308, HUGE_VAL, -HUGE_VAL, NAN, 1e15, 1e-15, 1e-16, 1e16, 1e-9, -1e-3,
    9.223372036854775807e18, 4294967296.0, 2147483648.0, -2147483649.0, 0.1, 97.3, 500.0};
#define N_INTERESTING (sizeof INTERESTING / sizeof INTERESTING[0])

static double f64(input *in)
{
    unsigned b = u8(in);
    if (b < 0xf0) return INTERESTING[b % N_INTERESTING];
    {
        uint64_t u = 0;
        double x;
        int k;
        for (k = 0; k < 8; k++) u |= (uint64_t)u8(in) << (8 * k);
        memcpy(&x, &u, sizeof x);
        return x;
    }
}

static unsigned vref(input *in)
{
    unsigned b = u8(in);
    return b < 0xf8 ? b % (FPM_MAX_VARS + 4) : 0xffffffffu - (b & 7);
}

/* ------------------------------------------------------------------ the oracle */
static int logged;                         /* messages since the last call */
static int verbose = -1;                   /* FUZZ_VERBOSE set: every message to stderr */

static void check_message(int status, const char *category, const char *message)
{
    if (verbose < 0) verbose = getenv("FUZZ_VERBOSE") != NULL;
    if (verbose) fprintf(stderr, "[%d] %s\n", status, message ? message : "(null)");
    if (category == NULL || message == NULL || strchr(message, '%') != NULL) {
        fprintf(stderr, "bad log message (status %d)\n", status);
        abort();
    }
    logged++;
}

static void logger2(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                    fmi2String category, fmi2String message, ...)
{
    (void)env;
    (void)name;
    check_message((int)status, category, message);
}

static void logger3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                    fmi3String message)
{
    (void)env;
    check_message((int)status, category, message);
}

/* No operation may take more CPU time than this (docs/fuzzing.md). A call's work is bounded by
 * the FMUs' caps (this build's FPM_MAX_SUBSTEPS and FPM_MAX_EXACT_WORK: a few hundredths of a
 * second of work without the sanitizers): a call over the limit is work that escapes them. The
 * thread's CPU time, not the wall clock: a busy machine does not change it. */
#ifndef CALL_LIMIT_S
#define CALL_LIMIT_S 2.0
#endif

static double cpu_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double op_start;
static unsigned op_now;

static void op_begin(unsigned op)
{
    op_now = op;
    op_start = cpu_seconds();
}

static void op_end(int fmi_version)
{
    double used = cpu_seconds() - op_start;
    if (used > CALL_LIMIT_S) {
        fprintf(stderr, "FMI %d operation %u took %.2f s of CPU time, over the limit of %g s\n",
                fmi_version, op_now, used, CALL_LIMIT_S);
        abort();
    }
}

/* every non-OK status of an instance's call comes with a message */
static int expect(int status, int have_instance, const char *fn)
{
    if (status != 0 && have_instance && logged == 0) {
        fprintf(stderr, "%s returned status %d without a log message\n", fn, status);
        abort();
    }
    logged = 0;
    return status;
}

static void expect_finite(int status, const double *v, size_t n, const char *fn)
{
    size_t i;
    if (status > 1) return;
    for (i = 0; i < n; i++)
        if (!isfinite(v[i])) {
            fprintf(stderr, "%s returned status %d with a value %g\n", fn, status, v[i]);
            abort();
        }
}

static void expect_time(int status, double t, double h, double now, const char *fn)
{
    if (status == 0 && now != t + h) {
        fprintf(stderr, "%s(%.17g, %.17g) returned OK but the FMU is at %.17g\n", fn, t, h, now);
        abort();
    }
}

static void expect_positive(int status, const double *v, size_t n, const char *fn)
{
    size_t i;
    expect_finite(status, v, n, fn);
    if (status > 1) return;
    for (i = 0; i < n; i++)
        if (!(v[i] > 0.0)) {
            fprintf(stderr, "%s returned status %d with a nominal %g\n", fn, status, v[i]);
            abort();
        }
}

/* ------------------------------------------------------------------ states */
static uint64_t fnv(const uint8_t *p, size_t n)
{
    uint64_t h = 14695981039346656037ULL;
    size_t i;
    for (i = 0; i < n; i++) {
        h ^= p[i];
        h *= 1099511628211ULL;
    }
    return h;
}

/* Recompute the trailer (the checksum of everything before it), as anyone can. */
static void fix_checksum(uint8_t *b, size_t n)
{
    uint64_t h;
    int k;
    if (n < 8) return;
    h = fnv(b, n - 8);
    for (k = 0; k < 8; k++) b[n - 8 + k] = (uint8_t)(h >> (8 * k));
}

/* Edits chosen by the input: a double, an int or a byte written at an offset. */
static void edit(input *in, uint8_t *b, size_t n)
{
    unsigned k, count = u8(in) % 6;
    for (k = 0; k < count && n > 16; k++) {
        unsigned kind = u8(in) % 3;
        size_t at = u16(in);
        at %= n;
        if (kind == 0 && at + 8 <= n) {
            double x = f64(in);
            memcpy(b + at, &x, 8);
        } else if (kind == 1 && at + 4 <= n) {
            unsigned lo = u16(in);
            int32_t x = (int32_t)(lo | (u16(in) << 16));
            memcpy(b + at, &x, 4);
        } else {
            b[at] ^= (uint8_t)u8(in);
        }
    }
}

static const char *const KNOWN[12] = {"rk4", "euler", "symplectic_euler", "dopri5",
                                      "exponential", "linear", "nonlinear", "radau", "exact",
                                      "stiffened", "modal", "kelvin-voigt"};

#define MAX_BLOB 65536
static uint8_t blob[MAX_BLOB];

/* ------------------------------------------------------------------ FMI 2.0 */
static void run2(input *in)
{
    fmi2CallbackFunctions cb = {logger2, calloc, free, NULL, NULL};
    fmi2Component c = NULL;
    fmi2FMUstate slot[2] = {NULL, NULL};
    fmi2ValueReference vr[4];
    double dv[4];
    int iv[4];
    fmi2String sv[4];
    char text[3][48];
    int s;
    while (more(in)) {
        unsigned op = u8(in) % 25;
        unsigned n = u8(in) % 5, k, a, b;
        int nul = n > 0 && u8(in) % 8 == 0;    /* a NULL array with a count */
        for (k = 0; k < 4; k++) {
            vr[k] = vref(in);
            dv[k] = f64(in);
            a = u16(in);
            iv[k] = (int)(int32_t)(a | (u16(in) << 16));
        }
        a = u8(in);                            /* two flags for the operation */
        b = u8(in);
        if (c == NULL && op != 0) op = 0;
        op_begin(op);
        logged = 0;
        switch (op) {
        case 0:
            if (c != NULL) break;
            c = fmi2Instantiate("fuzz", a % 8 == 0 ? fmi2ModelExchange : fmi2CoSimulation,
                                b % 16 == 0 ? "{wrong}" : fpm_token, "file:///tmp", &cb,
                                fmi2False, (a >> 4) & 1);
            logged = 0;
            if (c == NULL) return;
            break;
        case 1:
            expect(fmi2SetupExperiment(c, a & 1, dv[0], dv[1], b & 1, dv[2]), 1,
                   "fmi2SetupExperiment");
            break;
        case 2: expect(fmi2EnterInitializationMode(c), 1, "fmi2EnterInitializationMode"); break;
        case 3: expect(fmi2ExitInitializationMode(c), 1, "fmi2ExitInitializationMode"); break;
        case 4: case 5: {
            double now = 0.0, t, h = dv[1];
            fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &now);
            t = op == 4 ? now : dv[0];
            s = expect(fmi2DoStep(c, t, h, fmi2True), 1, "fmi2DoStep");
            fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &now);
            expect_time(s, t, h, now, "fmi2DoStep");
            break;
        }
        case 6:
            expect(fmi2SetReal(c, nul ? NULL : vr, n, dv), 1, "fmi2SetReal");
            break;
        case 7:
            expect(fmi2SetInteger(c, vr, n, nul ? NULL : iv), 1, "fmi2SetInteger");
            break;
        case 8:
            expect(fmi2SetBoolean(c, vr, n, iv), 1, "fmi2SetBoolean");
            break;
        case 9:
            for (k = 0; k < 3; k++) {
                unsigned len = u8(in) % 52, j;
                if (len >= 40) {                 /* a value the model knows */
                    strcpy(text[k], KNOWN[len - 40]);
                } else {
                    for (j = 0; j < len; j++) {
                        unsigned ch = u8(in);
                        text[k][j] = (char)(ch ? ch : 'x');
                    }
                    text[k][len] = '\0';
                }
                sv[k] = k == 2 && u8(in) % 4 == 0 ? NULL : text[k];
            }
            sv[3] = (a & 1) ? "rk4" : "linear";
            expect(fmi2SetString(c, vr, n, nul ? NULL : sv), 1, "fmi2SetString");
            break;
        case 10: case 11: {
            double out[FPM_MAX_VARS];
            fmi2ValueReference all[FPM_MAX_VARS];
            size_t m = 0;
            for (k = 0; k < FPM_MAX_VARS; k++)
                if (fpm_vars[k].name && fpm_vars[k].causality == FPM_OUTPUT) all[m++] = k;
            s = expect(fmi2GetReal(c, all, m, out), 1, "fmi2GetReal");
            expect_finite(s, out, m, "fmi2GetReal");
            s = expect(fmi2GetReal(c, nul ? NULL : vr, n, out), 1, "fmi2GetReal");
            if (s <= 1)                       /* outputs must be finite; inputs may be NaN */
                for (k = 0; k < n; k++)
                    if (fpm_lookup(vr[k]) >= 0 && fpm_vars[vr[k]].causality == FPM_OUTPUT)
                        expect_finite(s, &out[k], 1, "fmi2GetReal");
            break;
        }
        case 12:
            expect(fmi2GetInteger(c, vr, n, nul ? NULL : iv), 1, "fmi2GetInteger");
            expect(fmi2GetBoolean(c, vr, n, iv), 1, "fmi2GetBoolean");
            expect(fmi2GetString(c, vr, n, sv), 1, "fmi2GetString");
            break;
        case 13: expect(fmi2GetFMUstate(c, &slot[a & 1]), 1, "fmi2GetFMUstate"); break;
        case 14: {
            fmi2FMUstate st = slot[a & 1];
            if (st) expect(fmi2SetFMUstate(c, st), 1, "fmi2SetFMUstate");
            break;
        }
        case 15: expect(fmi2FreeFMUstate(c, &slot[a & 1]), 1, "fmi2FreeFMUstate"); break;
        case 16: case 17: case 18: {         /* serialise, edit, fix the trailer, restore */
            fmi2FMUstate st = NULL;
            size_t size = 0;
            int fix = op != 16 || (a & 1);
            if (expect(fmi2GetFMUstate(c, &st), 1, "fmi2GetFMUstate") != 0) break;
            if (expect(fmi2SerializedFMUstateSize(c, st, &size), 1, "size") == 0 &&
                size <= MAX_BLOB &&
                expect(fmi2SerializeFMUstate(c, st, (fmi2Byte *)blob, size), 1, "ser") == 0) {
                fmi2FMUstate back = NULL;
                if (op != 17) edit(in, blob, size);
                if (fix) fix_checksum(blob, size);
                if (expect(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)blob, size, &back), 1,
                           "fmi2DeSerializeFMUstate") == 0) {
                    expect(fmi2SetFMUstate(c, back), 1, "fmi2SetFMUstate");
                    expect(fmi2FreeFMUstate(c, &back), 1, "fmi2FreeFMUstate");
                }
            }
            expect(fmi2FreeFMUstate(c, &st), 1, "fmi2FreeFMUstate");
            break;
        }
        case 19: {                           /* a raw blob from the input */
            size_t size = u16(in) % 4096, j;
            fmi2FMUstate back = NULL;
            for (j = 0; j < size; j++) blob[j] = (uint8_t)u8(in);
            if (a & 1) fix_checksum(blob, size);
            if (expect(fmi2DeSerializeFMUstate(c, (const fmi2Byte *)blob, size, &back), 1,
                       "fmi2DeSerializeFMUstate") == 0) {
                expect(fmi2SetFMUstate(c, back), 1, "fmi2SetFMUstate");
                expect(fmi2FreeFMUstate(c, &back), 1, "fmi2FreeFMUstate");
            }
            break;
        }
        case 20:
            expect(a & 1 ? fmi2Terminate(c) : fmi2Reset(c), 1, "fmi2Terminate/Reset");
            break;
        case 21:
            expect(fmi2SetRealInputDerivatives(c, vr, n, nul ? NULL : iv, dv), 1,
                   "fmi2SetRealInputDerivatives");
            break;
        case 22: {
            fmi2Boolean bs;
            fmi2Real r;
            fmi2Status st;
            expect(fmi2GetBooleanStatus(c, (fmi2StatusKind)(a % 4), &bs), 1, "bstatus");
            expect(fmi2GetRealStatus(c, (fmi2StatusKind)(b % 4), a & 4 ? &r : NULL), 1,
                   "rstatus");
            expect(fmi2GetStatus(c, fmi2DoStepStatus, &st), 1, "status");
            expect(fmi2SetDebugLogging(c, b & 8, 0, NULL), 1, "fmi2SetDebugLogging");
            break;
        }
        case 24: {                               /* Model Exchange and the derivatives */
            double x[FPM_MAX_VARS], out[4];
            size_t m = (a & 16) ? (size_t)(b % 32) : (a & 32) ? fpm_model_nz() : fpm_model_nx();
            for (k = 0; k < FPM_MAX_VARS; k++) x[k] = dv[k % 4];
            switch (a % 13) {
            case 0: expect(fmi2EnterEventMode(c), 1, "fmi2EnterEventMode"); break;
            case 1: {
                fmi2EventInfo info;
                expect(fmi2NewDiscreteStates(c, b & 1 ? &info : NULL), 1,
                       "fmi2NewDiscreteStates");
                break;
            }
            case 2:
                expect(fmi2EnterContinuousTimeMode(c), 1, "fmi2EnterContinuousTimeMode");
                break;
            case 3: {
                fmi2Boolean e1, t1;
                expect(fmi2CompletedIntegratorStep(c, fmi2True, &e1, b & 1 ? &t1 : NULL), 1,
                       "fmi2CompletedIntegratorStep");
                break;
            }
            case 4: expect(fmi2SetTime(c, dv[0]), 1, "fmi2SetTime"); break;
            case 5:
                expect(fmi2SetContinuousStates(c, nul ? NULL : x, m), 1,
                       "fmi2SetContinuousStates");
                break;
            case 6:
                s = expect(fmi2GetDerivatives(c, nul ? NULL : x, m), 1, "fmi2GetDerivatives");
                if (!nul) expect_finite(s, x, m, "fmi2GetDerivatives");
                break;
            case 7:
                s = expect(fmi2GetEventIndicators(c, nul ? NULL : x, m), 1,
                           "fmi2GetEventIndicators");
                if (!nul) expect_finite(s, x, m, "fmi2GetEventIndicators");
                break;
            case 8:
                s = expect(fmi2GetContinuousStates(c, nul ? NULL : x, m), 1,
                           "fmi2GetContinuousStates");
                if (!nul) expect_finite(s, x, m, "fmi2GetContinuousStates");
                break;
            case 9:
                s = expect(fmi2GetNominalsOfContinuousStates(c, nul ? NULL : x, m), 1,
                           "fmi2GetNominalsOfContinuousStates");
                if (!nul) expect_positive(s, x, m, "fmi2GetNominalsOfContinuousStates");
                break;
            case 10:
                s = expect(fmi2GetDirectionalDerivative(c, vr, n % 3, nul ? NULL : vr + 2,
                                                        n / 2, dv, out), 1,
                           "fmi2GetDirectionalDerivative");
                expect_finite(s, out, n % 3, "fmi2GetDirectionalDerivative");
                break;
            default:
                s = expect(fmi2GetRealOutputDerivatives(c, vr, n, nul ? NULL : iv, out), 1,
                           "fmi2GetRealOutputDerivatives");
                expect_finite(s, out, n, "fmi2GetRealOutputDerivatives");
                break;
            }
            break;
        }
        default:
            for (k = 0; k < 2; k++) fmi2FreeFMUstate(c, &slot[k]);
            fmi2FreeInstance(c);
            c = NULL;
            break;
        }
        op_end(2);
    }
    if (c != NULL) {
        for (s = 0; s < 2; s++) fmi2FreeFMUstate(c, &slot[s]);
        fmi2FreeInstance(c);
    }
}

/* ------------------------------------------------------------------ FMI 3.0 */
static void run3(input *in)
{
    fmi3Instance c = NULL;
    fmi3FMUState slot[2] = {NULL, NULL};
    fmi3ValueReference vr[4];
    double dv[4];
    int32_t iv[4];
    fmi3Boolean bv[4];
    fmi3String sv[4];
    int s;
    while (more(in)) {
        unsigned op = u8(in) % 23;
        unsigned n = u8(in) % 5, k, nv, a, b;
        int nul = n > 0 && u8(in) % 8 == 0;
        nv = u8(in) % 16 == 0 ? n + 1 : n;     /* a count that does not match, sometimes */
        for (k = 0; k < 4; k++) {
            vr[k] = vref(in);
            dv[k] = f64(in);
            a = u16(in);
            iv[k] = (int32_t)(a | (u16(in) << 16));
            bv[k] = (fmi3Boolean)(u8(in) & 1);
            sv[k] = KNOWN[u8(in) % 12];
        }
        a = u8(in);                            /* two flags for the operation */
        b = u8(in);
        if (c == NULL && op != 0) op = 0;
        op_begin(op);
        logged = 0;
        switch (op) {
        case 0:
            if (c != NULL) break;
            if (b % 8 == 7)                  /* Model Exchange */
                c = fmi3InstantiateModelExchange("fuzz", a % 16 == 0 ? "{wrong}" : fpm_token,
                                                 "/tmp", fmi3False, b & 1, NULL, logger3);
            else
                c = fmi3InstantiateCoSimulation("fuzz", a % 16 == 0 ? "{wrong}" : fpm_token,
                                                "/tmp", fmi3False, b & 1, (b >> 1) & 1,
                                                fmi3False, NULL, 0, NULL, logger3, NULL);
            logged = 0;
            if (c == NULL) return;
            break;
        case 1:
            expect(fmi3EnterInitializationMode(c, a & 1, dv[0], dv[1], b & 1, dv[2]), 1,
                   "fmi3EnterInitializationMode");
            break;
        case 2: expect(fmi3ExitInitializationMode(c), 1, "fmi3ExitInitializationMode"); break;
        case 3: case 4: {
            fmi3Boolean ev, term, early;
            double last = 0.0, now = 0.0, t, h = dv[1];
            fmi3DoStep(c, -1.0, -1.0, fmi3True, &ev, &term, &early, &now);  /* the time */
            logged = 0;
            t = op == 3 ? now : dv[0];
            s = expect(fmi3DoStep(c, t, h, fmi3True, &ev, &term, &early, &last), 1,
                       "fmi3DoStep");
            expect_time(s, t, h, last, "fmi3DoStep");
            break;
        }
        case 5:
            if (a % 8 == 0)                      /* issue 23: NULL arrays with a count */
                expect(fmi3GetFloat64(c, NULL, 2, NULL, 2), 1, "fmi3GetFloat64");
            else
                expect(fmi3SetFloat64(c, nul ? NULL : vr, n, dv, nv), 1, "fmi3SetFloat64");
            break;
        case 6: expect(fmi3SetInt32(c, vr, n, nul ? NULL : iv, nv), 1, "fmi3SetInt32"); break;
        case 7: expect(fmi3SetBoolean(c, vr, n, bv, nv), 1, "fmi3SetBoolean"); break;
        case 8: expect(fmi3SetString(c, vr, n, nul ? NULL : sv, nv), 1, "fmi3SetString"); break;
        case 9: {
            double out[FPM_MAX_VARS];
            fmi3ValueReference all[FPM_MAX_VARS];
            size_t m = 0;
            for (k = 0; k < FPM_MAX_VARS; k++)
                if (fpm_vars[k].name && fpm_vars[k].causality == FPM_OUTPUT) all[m++] = k;
            s = expect(fmi3GetFloat64(c, all, m, out, m), 1, "fmi3GetFloat64");
            expect_finite(s, out, m, "fmi3GetFloat64");
            s = expect(fmi3GetFloat64(c, nul ? NULL : vr, n, out, nv), 1, "fmi3GetFloat64");
            if (s <= 1)
                for (k = 0; k < n; k++)
                    if (fpm_lookup(vr[k]) >= 0 && fpm_vars[vr[k]].causality == FPM_OUTPUT)
                        expect_finite(s, &out[k], 1, "fmi3GetFloat64");
            break;
        }
        case 10:
            expect(fmi3GetInt32(c, vr, n, nul ? NULL : iv, nv), 1, "fmi3GetInt32");
            expect(fmi3GetBoolean(c, vr, n, bv, nv), 1, "fmi3GetBoolean");
            expect(fmi3GetString(c, vr, n, sv, nv), 1, "fmi3GetString");
            break;
        case 11: {
            fmi3Float32 f[4];
            fmi3UInt64 u[4];
            expect(fmi3GetFloat32(c, nul ? NULL : vr, n, f, nv), 1, "fmi3GetFloat32");
            expect(fmi3SetUInt64(c, vr, n, nul ? NULL : u, nv), 1, "fmi3SetUInt64");
            break;
        }
        case 12: expect(fmi3GetFMUState(c, &slot[a & 1]), 1, "fmi3GetFMUState"); break;
        case 13: {
            fmi3FMUState st = slot[a & 1];
            if (st) expect(fmi3SetFMUState(c, st), 1, "fmi3SetFMUState");
            break;
        }
        case 14: expect(fmi3FreeFMUState(c, &slot[a & 1]), 1, "fmi3FreeFMUState"); break;
        case 15: case 16: {
            fmi3FMUState st = NULL;
            size_t size = 0;
            int fix = op == 15 || (a & 1);
            if (expect(fmi3GetFMUState(c, &st), 1, "fmi3GetFMUState") != 0) break;
            if (expect(fmi3SerializedFMUStateSize(c, st, &size), 1, "size") == 0 &&
                size <= MAX_BLOB &&
                expect(fmi3SerializeFMUState(c, st, blob, size), 1, "ser") == 0) {
                fmi3FMUState back = NULL;
                edit(in, blob, size);
                if (fix) fix_checksum(blob, size);
                if (expect(fmi3DeserializeFMUState(c, blob, size, &back), 1,
                           "fmi3DeserializeFMUState") == 0) {
                    expect(fmi3SetFMUState(c, back), 1, "fmi3SetFMUState");
                    expect(fmi3FreeFMUState(c, &back), 1, "fmi3FreeFMUState");
                }
            }
            expect(fmi3FreeFMUState(c, &st), 1, "fmi3FreeFMUState");
            break;
        }
        case 17: {
            size_t size = u16(in) % 4096, j;
            fmi3FMUState back = NULL;
            for (j = 0; j < size; j++) blob[j] = (uint8_t)u8(in);
            if (a & 1) fix_checksum(blob, size);
            if (expect(fmi3DeserializeFMUState(c, blob, size, &back), 1,
                       "fmi3DeserializeFMUState") == 0) {
                expect(fmi3SetFMUState(c, back), 1, "fmi3SetFMUState");
                expect(fmi3FreeFMUState(c, &back), 1, "fmi3FreeFMUState");
            }
            break;
        }
        case 18:
            switch (a % 4) {
            case 0: expect(fmi3Terminate(c), 1, "fmi3Terminate"); break;
            case 1: expect(fmi3Reset(c), 1, "fmi3Reset"); break;
            case 2: expect(fmi3EnterEventMode(c), 1, "fmi3EnterEventMode"); break;
            default: expect(fmi3EnterStepMode(c), 1, "fmi3EnterStepMode"); break;
            }
            break;
        case 19: {
            fmi3Boolean a, b, d, e, f;
            double t;
            expect(fmi3UpdateDiscreteStates(c, &a, &b, &d, &e, &f, &t), 1, "update");
            break;
        }
        case 20:
            expect(fmi3SetDebugLogging(c, a & 1, 0, NULL), 1, "fmi3SetDebugLogging");
            break;
        case 22: {                               /* Model Exchange and the derivatives */
            double x[FPM_MAX_VARS], out[4];
            size_t m = (a & 16) ? (size_t)(b % 32) : (a & 32) ? fpm_model_nz() : fpm_model_nx();
            for (k = 0; k < FPM_MAX_VARS; k++) x[k] = dv[k % 4];
            switch (a % 12) {
            case 0: expect(fmi3EnterEventMode(c), 1, "fmi3EnterEventMode"); break;
            case 1:
                expect(fmi3EnterContinuousTimeMode(c), 1, "fmi3EnterContinuousTimeMode");
                break;
            case 2: {
                fmi3Boolean e1, t1;
                expect(fmi3CompletedIntegratorStep(c, fmi3True, &e1, b & 1 ? &t1 : NULL), 1,
                       "fmi3CompletedIntegratorStep");
                break;
            }
            case 3: expect(fmi3SetTime(c, dv[0]), 1, "fmi3SetTime"); break;
            case 4:
                expect(fmi3SetContinuousStates(c, nul ? NULL : x, m), 1,
                       "fmi3SetContinuousStates");
                break;
            case 5:
                s = expect(fmi3GetContinuousStateDerivatives(c, nul ? NULL : x, m), 1,
                           "fmi3GetContinuousStateDerivatives");
                if (!nul) expect_finite(s, x, m, "fmi3GetContinuousStateDerivatives");
                break;
            case 6:
                s = expect(fmi3GetEventIndicators(c, nul ? NULL : x, m), 1,
                           "fmi3GetEventIndicators");
                if (!nul) expect_finite(s, x, m, "fmi3GetEventIndicators");
                break;
            case 7:
                s = expect(fmi3GetContinuousStates(c, nul ? NULL : x, m), 1,
                           "fmi3GetContinuousStates");
                if (!nul) expect_finite(s, x, m, "fmi3GetContinuousStates");
                break;
            case 8:
                s = expect(fmi3GetNominalsOfContinuousStates(c, nul ? NULL : x, m), 1,
                           "fmi3GetNominalsOfContinuousStates");
                if (!nul) expect_positive(s, x, m, "fmi3GetNominalsOfContinuousStates");
                break;
            case 9: {
                size_t nn = 0;
                expect(fmi3GetNumberOfContinuousStates(c, b & 1 ? &nn : NULL), 1, "nx");
                expect(fmi3GetNumberOfEventIndicators(c, b & 2 ? &nn : NULL), 1, "nz");
                break;
            }
            case 10:
                s = expect(fmi3GetDirectionalDerivative(c, vr, n % 3, nul ? NULL : vr + 2,
                                                        n / 2, dv, n / 2, out, n % 3), 1,
                           "fmi3GetDirectionalDerivative");
                expect_finite(s, out, n % 3, "fmi3GetDirectionalDerivative");
                break;
            default:
                s = expect(fmi3GetOutputDerivatives(c, vr, n, nul ? NULL : iv, out, n), 1,
                           "fmi3GetOutputDerivatives");
                expect_finite(s, out, n, "fmi3GetOutputDerivatives");
                break;
            }
            break;
        }
        default:
            for (k = 0; k < 2; k++) fmi3FreeFMUState(c, &slot[k]);
            fmi3FreeInstance(c);
            c = NULL;
            break;
        }
        op_end(3);
    }
    if (c != NULL) {
        for (s = 0; s < 2; s++) fmi3FreeFMUState(c, &slot[s]);
        fmi3FreeInstance(c);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    input in;
    in.p = data;
    in.n = size;
    in.i = 0;
    if (size == 0) return 0;
    if (u8(&in) & 1) run3(&in);
    else run2(&in);
    return 0;
}
