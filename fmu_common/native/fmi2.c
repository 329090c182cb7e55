/*
 * fmi2.c - the FMI 2.0 co-simulation interface, written once for every model (see fpm.h).
 *
 * Every function checks its instance and the state machine first (FMI 2.0, section 4.2.4) and
 * logs the reason for any status other than fmi2OK. Input derivatives (canInterpolateInputs):
 * fmi2SetRealInputDerivatives hands the first and second time derivatives of an input to the
 * model, which integrates the input polynomial over the following steps.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fpm.h"

/* States of the instance, as bits (several are allowed per call). */
#define S_INSTANTIATED 1
#define S_INIT 2
#define S_STEP 4
#define S_TERMINATED 8
#define S_ERROR 16
#define S_ANY (S_INSTANTIATED | S_INIT | S_STEP | S_TERMINATED | S_ERROR)

/* What an FMU state saves: the mode, then the model (aligned). */
typedef struct saved_head {
    int mode;
    int discarded;             /* the model refused the last doStep (the master should stop) */
    double align;
} saved_head;

typedef struct instance {
    fmi2CallbackFunctions cb;
    int logging_on;
    char name[128];
    fpm_logger lg;
    double start_time;
    saved_head *head;          /* head, then the model, in one block */
    fpm_model *m;
    size_t saved_size;         /* sizeof(saved_head) + the model's size */
} instance;

static const char *mode_name(int mode)
{
    switch (mode) {
    case S_INSTANTIATED: return "Instantiated";
    case S_INIT: return "InitializationMode";
    case S_STEP: return "StepComplete";
    case S_TERMINATED: return "Terminated";
    default: return "Error";
    }
}

static void emit(void *env, int status, const char *category, const char *message)
{
    instance *c = (instance *)env;
    if (c->cb.logger == NULL) return;
    if (status == FPM_OK && !c->logging_on) return;
    c->cb.logger(c->cb.componentEnvironment, c->name, (fmi2Status)status, category, message);
}

static void *alloc(instance *c, size_t n)
{
    void *p = c->cb.allocateMemory ? c->cb.allocateMemory(1, n) : calloc(1, n);
    if (p != NULL) memset(p, 0, n);
    return p;
}

static void release(instance *c, void *p)
{
    if (p == NULL) return;
    if (c->cb.freeMemory) c->cb.freeMemory(p);
    else free(p);
}

/* Check the instance and its state; log and return fmi2Error if the call is not allowed. */
static int allowed(instance *c, const char *fn, int states)
{
    if (c->head->mode & states) return 1;
    fpm_log(&c->lg, FPM_ERROR, "%s is not allowed in state %s", fn, mode_name(c->head->mode));
    return 0;
}

#define CHECK(fn, states)                                                                    \
    instance *c = (instance *)comp;                                                          \
    if (c == NULL) return fmi2Error;                                                         \
    if (!allowed(c, fn, states)) return fmi2Error

/* ------------------------------------------------------------------ common functions */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    CHECK("fmi2SetDebugLogging", S_ANY);
    (void)nCategories;
    (void)categories;
    c->logging_on = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    instance tmp, *c;
    (void)fmuResourceLocation;
    (void)visible;
    memset(&tmp, 0, sizeof tmp);
    if (functions != NULL) tmp.cb = *functions;
    tmp.lg.emit = emit;
    tmp.lg.env = &tmp;
    tmp.logging_on = loggingOn ? 1 : 0;
    strncpy(tmp.name, instanceName ? instanceName : "?", sizeof tmp.name - 1);
    if (fmuType != fmi2CoSimulation) {
        fpm_log(&tmp.lg, FPM_ERROR, "%s is a co-simulation FMU: fmi2Instantiate with fmuType = "
                "%d (model exchange) is not supported", fpm_model_name, (int)fmuType);
        return NULL;
    }
    if (fmuGUID == NULL || strcmp(fmuGUID, fpm_token) != 0) {
        fpm_log(&tmp.lg, FPM_ERROR, "fmi2Instantiate: the GUID %s is not this FMU's (%s): the "
                "modelDescription.xml and the binary come from different builds",
                fmuGUID ? fmuGUID : "(null)", fpm_token);
        return NULL;
    }
    c = (instance *)alloc(&tmp, sizeof *c);
    if (c == NULL) {
        fpm_log(&tmp.lg, FPM_ERROR, "fmi2Instantiate: out of memory");
        return NULL;
    }
    *c = tmp;
    c->lg.env = c;
    c->saved_size = sizeof(saved_head) + fpm_model_size();
    c->head = (saved_head *)alloc(c, c->saved_size);
    if (c->head == NULL) {
        fpm_log(&c->lg, FPM_ERROR, "fmi2Instantiate: out of memory");
        release(c, c);
        return NULL;
    }
    c->m = (fpm_model *)(c->head + 1);
    fpm_model_reset(c->m, 0.0);
    c->head->mode = S_INSTANTIATED;
    return c;
}

void fmi2FreeInstance(fmi2Component comp)
{
    instance *c = (instance *)comp;
    if (c == NULL) return;
    release(c, c->head);
    release(c, c);
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime)
{
    CHECK("fmi2SetupExperiment", S_INSTANTIATED);
    (void)toleranceDefined;
    (void)tolerance;
    if (!isfinite(startTime) || (stopTimeDefined && !(stopTime >= startTime))) {
        fpm_log(&c->lg, FPM_ERROR, "fmi2SetupExperiment: startTime = %.17g, stopTime = %.17g: the "
                "start must be finite and not after the stop", startTime, stopTime);
        return fmi2Error;
    }
    c->start_time = startTime;
    {   /* keep the values set so far, restart the model's time */
        fpm_values v = *fpm_model_values(c->m);
        fpm_model_reset(c->m, startTime);
        *fpm_model_values(c->m) = v;
    }
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp)
{
    CHECK("fmi2EnterInitializationMode", S_INSTANTIATED);
    c->head->mode = S_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp)
{
    int rc;
    CHECK("fmi2ExitInitializationMode", S_INIT);
    rc = fpm_model_init(c->m, &c->lg);
    if (rc > FPM_WARNING) {
        c->head->mode = S_ERROR;
        return fmi2Error;
    }
    c->head->mode = S_STEP;
    return (fmi2Status)rc;
}

fmi2Status fmi2Terminate(fmi2Component comp)
{
    CHECK("fmi2Terminate", S_STEP | S_ERROR);
    c->head->mode = S_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp)
{
    CHECK("fmi2Reset", S_ANY);
    memset(c->head, 0, c->saved_size);
    fpm_model_reset(c->m, 0.0);
    c->head->mode = S_INSTANTIATED;
    return fmi2OK;
}

/* ------------------------------------------------------------------ get and set */
/* The table entry of vr if it exists and has type `type`, else NULL (logged). */
static const fpm_var *variable(instance *c, const char *fn, fmi2ValueReference vr, int type)
{
    static const char *TYPE[] = {"Real", "Integer", "Boolean", "String"};
    int i = fpm_lookup(vr);
    if (i < 0) {
        fpm_log(&c->lg, FPM_ERROR, "%s: %s has no variable with value reference %u", fn,
                fpm_model_name, (unsigned)vr);
        return NULL;
    }
    if (fpm_vars[i].type != type) {
        fpm_log(&c->lg, FPM_ERROR, "%s: variable %s (value reference %u) is of type %s, not %s",
                fn, fpm_vars[i].name, (unsigned)vr, TYPE[fpm_vars[i].type], TYPE[type]);
        return NULL;
    }
    return &fpm_vars[i];
}

/* May `v` be set now? */
static int settable(instance *c, const char *fn, const fpm_var *v)
{
    if (v->causality == FPM_OUTPUT) {
        fpm_log(&c->lg, FPM_ERROR, "%s: %s is an output; it cannot be set", fn, v->name);
        return 0;
    }
    if (v->causality == FPM_PARAMETER && !(c->head->mode & (S_INSTANTIATED | S_INIT))) {
        fpm_log(&c->lg, FPM_ERROR, "%s: parameter %s is fixed: it can only be set before "
                "fmi2ExitInitializationMode (state: %s)", fn, v->name, mode_name(c->head->mode));
        return 0;
    }
    return 1;
}

#define SET_STATES (S_INSTANTIATED | S_INIT | S_STEP)

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[])
{
    size_t i;
    int worst = FPM_OK;
    CHECK("fmi2GetReal", S_ANY);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi2GetReal", vr[i], FPM_REAL);
        if (v == NULL) return fmi2Error;
        if (v->causality == FPM_OUTPUT) {
            int rc = fpm_model_get_output(c->m, &c->lg, vr[i], &value[i]);
            if (rc > FPM_WARNING) return (fmi2Status)rc;
            if (rc > worst) worst = rc;
        } else {
            value[i] = fpm_model_values(c->m)->real[vr[i]];
        }
    }
    return (fmi2Status)worst;
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[])
{
    size_t i;
    CHECK("fmi2GetInteger", S_ANY);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (variable(c, "fmi2GetInteger", vr[i], FPM_INTEGER) == NULL) return fmi2Error;
        value[i] = (fmi2Integer)fpm_model_values(c->m)->real[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[])
{
    size_t i;
    CHECK("fmi2GetBoolean", S_ANY);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (variable(c, "fmi2GetBoolean", vr[i], FPM_BOOLEAN) == NULL) return fmi2Error;
        value[i] = fpm_model_values(c->m)->real[vr[i]] != 0.0 ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[])
{
    size_t i;
    CHECK("fmi2GetString", S_ANY);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        if (variable(c, "fmi2GetString", vr[i], FPM_STRING) == NULL) return fmi2Error;
        value[i] = fpm_model_values(c->m)->string[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[])
{
    size_t i;
    CHECK("fmi2SetReal", SET_STATES);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi2SetReal", vr[i], FPM_REAL);
        if (v == NULL || !settable(c, "fmi2SetReal", v)) return fmi2Error;
        fpm_model_values(c->m)->real[vr[i]] = value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[])
{
    size_t i;
    CHECK("fmi2SetInteger", SET_STATES);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi2SetInteger", vr[i], FPM_INTEGER);
        if (v == NULL || !settable(c, "fmi2SetInteger", v)) return fmi2Error;
        fpm_model_values(c->m)->real[vr[i]] = (double)value[i];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[])
{
    size_t i;
    CHECK("fmi2SetBoolean", SET_STATES);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi2SetBoolean", vr[i], FPM_BOOLEAN);
        if (v == NULL || !settable(c, "fmi2SetBoolean", v)) return fmi2Error;
        fpm_model_values(c->m)->real[vr[i]] = value[i] ? 1.0 : 0.0;
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[])
{
    size_t i;
    CHECK("fmi2SetString", SET_STATES);
    if (nvr > 0 && (vr == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi2SetString", vr[i], FPM_STRING);
        if (v == NULL || !settable(c, "fmi2SetString", v)) return fmi2Error;
        if (value[i] == NULL || strlen(value[i]) >= FPM_STR_MAX) {
            fpm_log(&c->lg, FPM_ERROR, "fmi2SetString: the value of %s is %s (at most %d "
                    "characters)", v->name, value[i] ? "too long" : "NULL", FPM_STR_MAX - 1);
            return fmi2Error;
        }
        strcpy(fpm_model_values(c->m)->string[vr[i]], value[i]);
    }
    return fmi2OK;
}

/* ------------------------------------------------------------------ FMU states */
fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *state)
{
    CHECK("fmi2GetFMUstate", S_ANY);
    if (state == NULL) return fmi2Error;
    if (*state == NULL) {
        *state = alloc(c, c->saved_size);
        if (*state == NULL) {
            fpm_log(&c->lg, FPM_ERROR, "fmi2GetFMUstate: out of memory");
            return fmi2Error;
        }
    }
    memcpy(*state, c->head, c->saved_size);
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate state)
{
    CHECK("fmi2SetFMUstate", S_ANY);
    if (state == NULL) {
        fpm_log(&c->lg, FPM_ERROR, "fmi2SetFMUstate: the state is NULL");
        return fmi2Error;
    }
    memcpy(c->head, state, c->saved_size);
    if (fpm_model_relink(c->m, &c->lg) != FPM_OK) {
        c->head->mode = S_ERROR;
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *state)
{
    CHECK("fmi2FreeFMUstate", S_ANY);
    if (state == NULL) return fmi2OK;
    release(c, *state);
    *state = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate state, size_t *size)
{
    CHECK("fmi2SerializedFMUstateSize", S_ANY);
    (void)state;
    if (size == NULL) return fmi2Error;
    *size = fpm_serialized_size(c->saved_size);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate state, fmi2Byte data[],
                                 size_t size)
{
    CHECK("fmi2SerializeFMUstate", S_ANY);
    if (state == NULL || data == NULL || size < fpm_serialized_size(c->saved_size)) {
        fpm_log(&c->lg, FPM_ERROR, "fmi2SerializeFMUstate: need a state and %lu bytes, got %lu",
                (unsigned long)fpm_serialized_size(c->saved_size), (unsigned long)size);
        return fmi2Error;
    }
    fpm_serialize(state, c->saved_size, (unsigned char *)data);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte data[], size_t size,
                                   fmi2FMUstate *state)
{
    char why[FPM_MSG_MAX];
    void *buf;
    CHECK("fmi2DeSerializeFMUstate", S_ANY);
    if (state == NULL) return fmi2Error;
    buf = alloc(c, c->saved_size);
    if (buf == NULL) return fmi2Error;
    if (fpm_deserialize((const unsigned char *)data, size, buf, c->saved_size, why) != FPM_OK) {
        fpm_log(&c->lg, FPM_ERROR, "fmi2DeSerializeFMUstate: %s", why);
        release(c, buf);
        return fmi2Error;
    }
    {   /* check that the payload is a state of this model before handing it out */
        saved_head *h = (saved_head *)buf;
        fpm_model *m = (fpm_model *)(h + 1);
        if (!(h->mode & S_ANY) || fpm_model_relink(m, &c->lg) != FPM_OK) {
            fpm_log(&c->lg, FPM_ERROR, "fmi2DeSerializeFMUstate: the data are not a valid state");
            release(c, buf);
            return fmi2Error;
        }
    }
    if (*state != NULL) release(c, *state);
    *state = buf;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown[],
                                        size_t nUnknown, const fmi2ValueReference vKnown[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[])
{
    CHECK("fmi2GetDirectionalDerivative", S_ANY);
    (void)vUnknown; (void)nUnknown; (void)vKnown; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    fpm_log(&c->lg, FPM_ERROR, "fmi2GetDirectionalDerivative: not provided by this FMU "
            "(providesDirectionalDerivative = false)");
    return fmi2Error;
}

/* ------------------------------------------------------------------ co-simulation */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[])
{
    size_t i;
    CHECK("fmi2SetRealInputDerivatives", SET_STATES);
    if (nvr > 0 && (vr == NULL || order == NULL || value == NULL)) return fmi2Error;
    for (i = 0; i < nvr; i++) {
        const fpm_var *v = variable(c, "fmi2SetRealInputDerivatives", vr[i], FPM_REAL);
        int rc;
        if (v == NULL) return fmi2Error;
        if (v->causality != FPM_INPUT) {
            fpm_log(&c->lg, FPM_ERROR, "fmi2SetRealInputDerivatives: %s is not an input",
                    v->name);
            return fmi2Error;
        }
        rc = fpm_model_set_input_derivative(c->m, &c->lg, vr[i], order[i], value[i]);
        if (rc != FPM_OK) return (fmi2Status)rc;
    }
    return fmi2OK;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[], fmi2Real value[])
{
    CHECK("fmi2GetRealOutputDerivatives", S_ANY);
    (void)vr; (void)order; (void)value;
    if (nvr == 0) return fmi2OK;
    fpm_log(&c->lg, FPM_ERROR, "fmi2GetRealOutputDerivatives: not provided by this FMU "
            "(maxOutputDerivativeOrder = 0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    double t = currentCommunicationPoint, h = communicationStepSize, own;
    CHECK("fmi2DoStep", S_STEP);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!(h > 0.0) || !isfinite(h) || !isfinite(t)) {
        fpm_log(&c->lg, FPM_DISCARD, "fmi2DoStep: communicationStepSize = %.17g at t = %.17g: the "
                "step must be positive and finite, and the time finite; step rejected, state "
                "unchanged", h, t);
        return fmi2Discard;
    }
    own = fpm_model_time(c->m);
    if (!(fabs(t - own) <= FPM_TIME_RTOL * (fabs(own) > 1.0 ? fabs(own) : 1.0))) {
        fpm_log(&c->lg, FPM_ERROR, "fmi2DoStep called at t = %.17g but the FMU is at t = %.17g; "
                "restore a saved FMU state to step from another time", t, own);
        return fmi2Error;
    }
    {
        int rc = fpm_model_step(c->m, &c->lg, t, h);
        c->head->discarded = rc == FPM_DISCARD;
        return (fmi2Status)rc;
    }
}

fmi2Status fmi2CancelStep(fmi2Component comp)
{
    CHECK("fmi2CancelStep", S_ANY);
    fpm_log(&c->lg, FPM_ERROR, "fmi2CancelStep: doStep is synchronous here (nothing to cancel)");
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value)
{
    CHECK("fmi2GetStatus", S_ANY);
    (void)value;
    fpm_log(&c->lg, FPM_DISCARD, "fmi2GetStatus(%d): not available (doStep is synchronous)",
            (int)s);
    return fmi2Discard;
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value)
{
    CHECK("fmi2GetRealStatus", S_ANY);
    if (s == fmi2LastSuccessfulTime && value != NULL) {
        *value = fpm_model_time(c->m);
        return fmi2OK;
    }
    fpm_log(&c->lg, FPM_DISCARD, "fmi2GetRealStatus(%d): only fmi2LastSuccessfulTime is "
            "available", (int)s);
    return fmi2Discard;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value)
{
    CHECK("fmi2GetIntegerStatus", S_ANY);
    (void)value;
    fpm_log(&c->lg, FPM_DISCARD, "fmi2GetIntegerStatus(%d): not available", (int)s);
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value)
{
    CHECK("fmi2GetBooleanStatus", S_ANY);
    if (s == fmi2Terminated && value != NULL) {
        /* after the model refused a step it cannot go on by itself (a master that restores a
         * saved state still can): a simple master (fmpy.simulate_fmu) stops instead of
         * retrying the same step forever */
        *value = c->head->discarded ? fmi2True : fmi2False;
        return fmi2OK;
    }
    fpm_log(&c->lg, FPM_DISCARD, "fmi2GetBooleanStatus(%d): only fmi2Terminated is available",
            (int)s);
    return fmi2Discard;
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value)
{
    CHECK("fmi2GetStringStatus", S_ANY);
    (void)value;
    fpm_log(&c->lg, FPM_DISCARD, "fmi2GetStringStatus(%d): not available", (int)s);
    return fmi2Discard;
}

/* ------------------------------------------------------------------ model exchange: not this FMU */
#define NOT_ME(fn)                                                                           \
    instance *c = (instance *)comp;                                                          \
    if (c != NULL)                                                                           \
        fpm_log(&c->lg, FPM_ERROR, "%s: %s is a co-simulation FMU (no model exchange)", fn,  \
                fpm_model_name);                                                             \
    return fmi2Error

fmi2Status fmi2EnterEventMode(fmi2Component comp) { NOT_ME("fmi2EnterEventMode"); }
fmi2Status fmi2NewDiscreteStates(fmi2Component comp, fmi2EventInfo *info)
{
    (void)info;
    NOT_ME("fmi2NewDiscreteStates");
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component comp)
{
    NOT_ME("fmi2EnterContinuousTimeMode");
}
fmi2Status fmi2CompletedIntegratorStep(fmi2Component comp, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    NOT_ME("fmi2CompletedIntegratorStep");
}
fmi2Status fmi2SetTime(fmi2Component comp, fmi2Real time)
{
    (void)time;
    NOT_ME("fmi2SetTime");
}
fmi2Status fmi2SetContinuousStates(fmi2Component comp, const fmi2Real x[], size_t nx)
{
    (void)x; (void)nx;
    NOT_ME("fmi2SetContinuousStates");
}
fmi2Status fmi2GetDerivatives(fmi2Component comp, fmi2Real derivatives[], size_t nx)
{
    (void)derivatives; (void)nx;
    NOT_ME("fmi2GetDerivatives");
}
fmi2Status fmi2GetEventIndicators(fmi2Component comp, fmi2Real eventIndicators[], size_t ni)
{
    (void)eventIndicators; (void)ni;
    NOT_ME("fmi2GetEventIndicators");
}
fmi2Status fmi2GetContinuousStates(fmi2Component comp, fmi2Real x[], size_t nx)
{
    (void)x; (void)nx;
    NOT_ME("fmi2GetContinuousStates");
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component comp, fmi2Real x_nominal[], size_t nx)
{
    (void)x_nominal; (void)nx;
    NOT_ME("fmi2GetNominalsOfContinuousStates");
}
